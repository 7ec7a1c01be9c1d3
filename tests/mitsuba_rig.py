"""A projector-camera rig rendered with Mitsuba 3: the independent reference for the simulator.

The rig reproduces what FORMAT.md "What a simulated frame holds" defines, with Mitsuba's
``volpath`` integrator (CPU variant ``scalar_rgb``) instead of ringlight's photon tracer:

- **Units.** One scene unit is one grid step, so the coefficients given here are per grid step
  (Mitsuba's ``sigma_t`` is per scene unit). The surface is the plane ``z = 0``; the medium fills
  the box ``|x|, |y| <= half_width``, ``-depth <= z <= 0`` (ringlight's volume repeats sideways
  without end; ``half_width`` makes the walls far enough to lose nothing measurable). The lit
  pixel is the unit square centred on the origin, where coordinates are small, so Mitsuba's
  relative ray offsets (about 1e-4 of a coordinate's size) stay far below anything measured.
- **Boundary.** At ``n = 1`` every face is ``null`` (index-matched). At ``n > 1`` the top face
  is a smooth ``dielectric`` and the walls and bottom stay ``null``, as in ringlight, where light
  crossing ``z = depth`` is lost. A stock dielectric stops every shadow ray (a point-like
  projector cannot be reached through a delta interface), so the lit pixel's patch carries
  :class:`FresnelPassBSDF`: it passes shadow rays with transmission 1 - F and defers everything
  else to the stock dielectric. That is exact for a beam at normal incidence, which refracts
  without turning and carries 1 - F of its power inside (irradiance, so no n^2 factor).
- **Projector.** Mitsuba's ``projector`` emitter (a pinhole projecting a texture) placed
  ``PROJECTOR_DISTANCE`` grid steps away along the beam, its frustum cut to the lit pixel. Its
  rays diverge by at most 0.0007 rad: the beam's power is exact and it widens by 0.01 grid
  steps per ten steps of depth (4e-4 of singly scattered light lands beside the lit pixel). The other
  emitters do not fit: ``directional`` lights the whole plane, ``spot`` a disc, and an area
  emitter is not collimated (``directionalarea`` is, but next-event estimation cannot reach
  it). ``scale`` makes the power through the pixel 1 (the irradiance on the plane across the
  axis at distance z is pi x scale / z^2, projector.cpp). A white Lambertian surface then
  reads 1 at the lit pixel and 0 elsewhere (:func:`render_white_patch`), which checks this
  calibration, the beam's footprint and the camera's pixels. An oblique projector (``n = 1``
  only: the pass-through is exact only at normal incidence) has a cross-section of
  1 x cos(zenith), which lands as the 1 x 1 pixel: the central rows of an N x N texture, so
  cos(zenith) must be a ratio of small integers (60 or 41.41 degrees).
- **Camera.** An ``orthographic`` sensor with a ``box`` reconstruction filter (the default
  Gaussian spreads each sample over neighbours; issue 18 saw the lit pixel 36 % low), ``size`` x
  ``size`` pixels centred on the lit one, its image plane scaled so that each pixel covers one
  grid step on the surface (cos(zenith) wide along the tilt for an oblique camera). A pixel's
  value is then the radiance toward the camera averaged over that surface pixel. Each render
  takes its own seed.
- **Units of the result.** reflectance factor = pi x radiance x pixel area / beam power, with
  pixel area 1 and beam power 1. Mitsuba's ``moment`` integrator gives each pixel's second
  moment, hence its standard error (samples are independent and the box filter gives each
  sample to one pixel).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import mitsuba as mi
import numpy as np

mi.set_variant("scalar_rgb")

PROJECTOR_DISTANCE = 1000.0
"""Grid steps from the lit pixel to the projector's pinhole."""

CAMERA_DISTANCE = 100.0
"""Grid steps from the lit pixel to the orthographic camera's image plane."""


@dataclass(frozen=True)
class Slab:
    """A homogeneous slab under a flat surface; coefficients per grid step."""

    mus: float
    mua: float
    g: float
    n: float
    depth: float
    half_width: float = 40.0


@dataclass(frozen=True)
class Render:
    """A rendered frame in reflectance-factor units.

    Attributes
    ----------
    image
        (size, size) float64 reflectance factor; the lit pixel at the centre.
    standard_error
        (size, size) float64 standard error of each pixel.
    seconds
        Wall time of the render.
    """

    image: np.ndarray
    standard_error: np.ndarray
    seconds: float


class FresnelPassBSDF(mi.BSDF):
    """A smooth dielectric that lets shadow rays through with transmission 1 - F.

    Mitsuba's volpath evaluates ``eval_null_transmission`` on every surface a shadow ray
    crosses; the stock dielectric returns 0 there. Everything else (camera and scattered
    rays) is the stock ``dielectric``'s sampling.
    """

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.eta = props["int_ior"]
        self.dielectric = mi.load_dict({"type": "dielectric", "int_ior": self.eta, "ext_ior": 1.0})
        self.m_flags = self.dielectric.m_flags
        self.m_components = self.dielectric.m_components

    def sample(self, ctx, si, sample1, sample2, active=True):
        return self.dielectric.sample(ctx, si, sample1, sample2, active)

    def eval(self, ctx, si, wo, active=True):
        return self.dielectric.eval(ctx, si, wo, active)

    def pdf(self, ctx, si, wo, active=True):
        return self.dielectric.pdf(ctx, si, wo, active)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.dielectric.eval_pdf(ctx, si, wo, active)

    def eval_null_transmission(self, si, active=True):
        reflected = mi.fresnel(mi.Frame3f.cos_theta(si.wi), self.eta)[0]
        return mi.Color3f(1.0 - reflected)

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"FresnelPassBSDF[eta={self.eta}]"


mi.register_bsdf("ringlight_fresnel_pass", lambda props: FresnelPassBSDF(props))


def direction(zenith_deg: float, azimuth_deg: float) -> np.ndarray:
    """(3,) unit vector of travel, ``zenith_deg`` from straight down (-z), azimuth from +x."""
    zenith, azimuth = math.radians(zenith_deg), math.radians(azimuth_deg)
    return np.array([math.sin(zenith) * math.cos(azimuth), math.sin(zenith) * math.sin(azimuth),
                     -math.cos(zenith)])


def _rectangle(x0, x1, y0, y1, z, bsdf, medium, normal=1.0) -> dict:
    """An axis-aligned rectangle in a plane ``z = const`` with its normal along ``normal`` x +z."""
    flip = mi.ScalarTransform4f().scale([1.0, normal, normal])  # rotates +z to -z, keeps handedness
    return {
        "type": "rectangle", "bsdf": bsdf, "interior": medium,
        "to_world": mi.ScalarTransform4f().translate([(x0 + x1) / 2, (y0 + y1) / 2, z])
        @ mi.ScalarTransform4f().scale([(x1 - x0) / 2, (y1 - y0) / 2, 1.0]) @ flip,
    }


def _wall(axis: int, side: float, half: float, depth: float, bsdf, medium) -> dict:
    """A side wall at ``axis = side * half`` spanning the slab's depth, normal pointing out."""
    # A rectangle's normal is +z; rotate it to +-x or +-y.
    rotation = (mi.ScalarTransform4f().rotate([0, 1, 0], 90 * side) if axis == 0
                else mi.ScalarTransform4f().rotate([1, 0, 0], -90 * side))
    centre = [0.0, 0.0, -depth / 2]
    centre[axis] = side * half
    scale = [depth / 2, half, 1.0] if axis == 0 else [half, depth / 2, 1.0]
    return {"type": "rectangle", "bsdf": bsdf, "interior": medium,
            "to_world": mi.ScalarTransform4f().translate(centre) @ rotation
            @ mi.ScalarTransform4f().scale(scale)}


def _slab_shapes(slab: Slab, pass_everywhere: bool) -> dict:
    """The slab as rectangles: the top split into the lit pixel's patch and four strips."""
    medium = {"type": "ref", "id": "slab"}  # one medium object, whichever face a ray enters by
    null = {"type": "null"}
    if slab.n == 1.0:
        patch = strips = null
    else:
        patch = {"type": "ringlight_fresnel_pass", "int_ior": slab.n}
        strips = patch if pass_everywhere else {"type": "dielectric", "int_ior": slab.n, "ext_ior": 1.0}
    half, h = slab.half_width, 0.5
    shapes = {
        "slab": {"type": "homogeneous", "sigma_t": slab.mus + slab.mua,
                 "albedo": slab.mus / (slab.mus + slab.mua),
                 "phase": {"type": "isotropic"} if slab.g == 0 else {"type": "hg", "g": slab.g}},
        "patch": _rectangle(-h, h, -h, h, 0.0, patch, medium),
        "left": _rectangle(-half, -h, -half, half, 0.0, strips, medium),
        "right": _rectangle(h, half, -half, half, 0.0, strips, medium),
        "front": _rectangle(-h, h, -half, -h, 0.0, strips, medium),
        "back": _rectangle(-h, h, h, half, 0.0, strips, medium),
        "bottom": _rectangle(-half, half, -half, half, -slab.depth, null, medium, normal=-1.0),
    }
    for axis in 0, 1:
        for side in -1.0, 1.0:
            shapes[f"wall{axis}{side:+.0f}"] = _wall(axis, side, half, slab.depth, null, medium)
    return shapes


def _camera(zenith_deg: float, azimuth_deg: float, size: int, spp: int, seed: int) -> dict:
    """An orthographic camera whose ``size`` x ``size`` pixels land on the grid's pixels."""
    view = direction(zenith_deg, azimuth_deg)
    azimuth = math.radians(azimuth_deg)
    up = [-math.sin(azimuth), math.cos(azimuth), 0.0]
    # look_at's camera x axis, up x view, lies in the tilt plane: pixels cos(zenith) wide
    # along it project onto one grid step of the surface.
    half = size / 2
    to_world = (mi.ScalarTransform4f().look_at(origin=(-CAMERA_DISTANCE * view).tolist(),
                                               target=[0.0, 0.0, 0.0], up=up)
                @ mi.ScalarTransform4f().scale([half * math.cos(math.radians(zenith_deg)), half, 1.0]))
    return {
        "type": "orthographic", "to_world": to_world, "near_clip": 1.0,
        "far_clip": 2 * CAMERA_DISTANCE,
        "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                 "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
    }


def _projector(zenith_deg: float, azimuth_deg: float) -> dict:
    """A unit-power collimated beam over the lit pixel (see the module notes)."""
    cos_zenith = math.cos(math.radians(zenith_deg))
    # The lit rows of an N x N texture make the cross-section 1 x cos(zenith), the image's y axis
    # lying in the tilt plane, so that it lands on the surface as the 1 x 1 pixel. (Mitsuba
    # turns a constant bitmap into a 2 x 2 one, so the unlit rows also keep the aspect square.)
    size, lit = next(((size, lit) for size in range(1, 17) for lit in range(1, size + 1)
                      if (size - lit) % 2 == 0 and abs(lit / size - cos_zenith) < 1e-9), (0, 0))
    if not size:
        raise ValueError(f"projector zenith {zenith_deg} deg: cos(zenith) is not a ratio of small integers")
    texture = np.zeros((size, size, 3), np.float32)
    texture[(size - lit) // 2:(size + lit) // 2] = 1.0
    beam = direction(zenith_deg, azimuth_deg)
    azimuth = math.radians(azimuth_deg)
    # look_at's image x axis is up x beam: across the tilt plane for this choice of up.
    up = [math.cos(azimuth), math.sin(azimuth), 0.0]
    cross_section = lit / size  # grid steps^2 at the pixel's distance
    return {
        "type": "projector", "fov": math.degrees(2 * math.atan(0.5 / PROJECTOR_DISTANCE)), "fov_axis": "x",
        "irradiance": {"type": "bitmap", "bitmap": mi.Bitmap(texture),
                       "filter_type": "nearest", "raw": True},
        # The irradiance across the axis at distance z is pi x scale / z^2 (projector.cpp).
        "scale": PROJECTOR_DISTANCE**2 / (math.pi * cross_section),
        "to_world": mi.ScalarTransform4f().look_at(origin=(-PROJECTOR_DISTANCE * beam).tolist(),
                                                   target=[0.0, 0.0, 0.0], up=up),
    }


def _render(scene_dict: dict, spp: int, seed: int) -> Render:
    """Render with the moment integrator; pixel values times pi (unit beam power, unit area)."""
    started = time.perf_counter()
    scene = mi.load_dict(scene_dict)
    channels = dict(zip(["R", "G", "B", *scene.integrator().aov_names()], range(64)))
    result = np.array(mi.render(scene, spp=spp, seed=seed), np.float64)
    # Grey media give grey samples, so Y (whose weights sum to 1 over equal R, G, B) is the value.
    mean, second = result[..., channels["nested.Y"]], result[..., channels["m2_nested.Y"]]
    variance = np.maximum(second - mean**2, 0.0) * spp / (spp - 1)
    return Render(image=math.pi * mean, standard_error=math.pi * np.sqrt(variance / spp),
                  seconds=time.perf_counter() - started)


def _scene(shapes: dict, emitter: dict, camera: dict, max_depth: int = -1) -> dict:
    scene = {"type": "scene",
             "integrator": {"type": "moment", "nested": {"type": "volpath", "max_depth": max_depth}},
             "sensor": camera, "emitter": emitter}
    scene.update(shapes)
    return scene


def render_impulse(slab: Slab, camera: tuple[float, float] = (0.0, 0.0),
                   projector: tuple[float, float] = (0.0, 0.0), size: int = 9, spp: int = 1024,
                   seed: int = 0, max_depth: int = -1) -> Render:
    """The frame of one lit pixel: ``size`` x ``size`` (odd) pixels centred on it.

    ``camera`` and ``projector`` are [zenith, azimuth] in degrees as in FORMAT.md;
    ``max_depth`` is volpath's (-1: unlimited; each scattering and each crossing of a
    dielectric counts one).
    """
    if projector[0] and slab.n != 1.0:
        raise ValueError("an oblique projector is exact only for an index-matched slab")
    return _render(_scene(_slab_shapes(slab, pass_everywhere=False), _projector(*projector),
                          _camera(*camera, size, spp, seed), max_depth), spp, seed)


def render_uniform(slab: Slab, camera: tuple[float, float] = (0.0, 0.0), size: int = 3,
                   spp: int = 1024, seed: int = 0) -> Render:
    """The frame under a uniform collimated beam straight down of unit irradiance.

    By linearity and translation invariance each pixel is the sum over the plane of one lit
    pixel's frame: the reflectance factor for light in along the normal and out toward the
    camera.
    """
    # Mitsuba's directional emitter: irradiance on a plane across the beam.
    light = {"type": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": 1.0}
    return _render(_scene(_slab_shapes(slab, pass_everywhere=True), light,
                          _camera(*camera, size, spp, seed)), spp, seed)


def render_white_patch(camera: tuple[float, float] = (0.0, 0.0),
                       projector: tuple[float, float] = (0.0, 0.0), size: int = 3,
                       spp: int = 16) -> Render:
    """The frame of a white Lambertian plane: 1 at the lit pixel and 0 elsewhere when the
    projector's power, the camera's pixels and the units are right."""
    plane = {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 1.0},
             "to_world": mi.ScalarTransform4f().scale([10.0, 10.0, 1.0])}
    return _render(_scene({"plane": plane}, _projector(*projector),
                          _camera(*camera, size, spp, 0)), spp, 0)


def radial_profile(image: np.ndarray, standard_error: np.ndarray | None = None,
                   radii=range(5)) -> tuple[np.ndarray, np.ndarray | None]:
    """Mean of ``image`` (size, size; lit pixel at the centre) over the pixels whose distance
    ``|d|`` from the lit pixel lies in ``[r - 0.5, r + 0.5)``, for each ``r`` in ``radii``.

    Returns (len(radii),) means and, when ``standard_error`` (per pixel, independent) is given,
    their standard errors; else None.
    """
    centre = image.shape[0] // 2
    yy, xx = np.mgrid[:image.shape[0], :image.shape[1]] - centre
    distance = np.hypot(yy, xx)
    means, errors = [], []
    for r in radii:
        ring = (distance >= r - 0.5) & (distance < r + 0.5)
        if r > centre:
            raise ValueError(f"radius {r} does not fit in a {image.shape[0]}-pixel image")
        means.append(image[ring].mean())
        if standard_error is not None:
            errors.append(math.sqrt((standard_error[ring] ** 2).sum()) / ring.sum())
    return np.array(means), (np.array(errors) if standard_error is not None else None)
