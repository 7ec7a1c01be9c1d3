"""Material tables for one photon walk that serves several colour channels at once.

Channels whose materials scatter alike (the same ``mus`` and ``g`` in every material; only the
absorption ``mua`` differs, as in most translucent materials and every preset but one) share
their walks: each walk carries one weight per channel, and each channel's weight is the
likelihood ratio of its own walk to the shared one, so every channel's estimate stays unbiased
while the random walk, its free paths and scatterings, are paid for once.

Delta tracking against a majorant ``M``: the shared walk takes a tentative collision as real
with probability ``mu_w / M``, where ``mu_w = mus + min_c mua_c`` (the least absorbing
channel's ``mu_t``). Channel ``c``'s own walk (implicit capture) would take it as real with
probability ``mu_t_c / M`` and then keep ``albedo_c = mus / mu_t_c`` of its weight, so its
weight is multiplied by

    mu_t_c / mu_w * albedo_c = mus / mu_w      at a real collision (the same for every channel),
    (M - mu_t_c) / (M - mu_w)                  at a null one (1 for the least absorbing channel).

With one channel this is exactly implicit capture (factors ``albedo`` and 1). A null factor far
below 1 would make the weights noisy (0 would be analogue absorption), so the majorant is raised
until every null factor is at least :data:`NULL_FACTOR_FLOOR`; the extra null collisions cost
little (a random number and a voxel lookup each).

Layout of the (rows, materials) float64 ``tables`` array the kernels take: rows
:data:`WALK_MU`, :data:`SCATTER`, :data:`ANISOTROPY`, then ``C`` rows of ``mu_t`` per channel
from :data:`MU_T`, then ``C`` rows of null factors; units per grid step.
"""

from __future__ import annotations

import numba
import numpy as np

WALK_MU, SCATTER, ANISOTROPY, MU_T = range(4)
NULL_FACTOR_FLOOR = 0.75


def walk_tables(mus: np.ndarray, mua: np.ndarray, g: np.ndarray, used: np.ndarray | None = None
                ) -> tuple[np.ndarray, float]:
    """``(tables, majorant)`` for materials with scattering ``mus`` (M,), absorption ``mua``
    (C, M) (one row per channel sharing the walk) and anisotropy ``g`` (M,), per grid step;
    the majorant covers the materials ``used`` (indices; all when None)."""
    mus = np.asarray(mus, np.float64)
    mua = np.atleast_2d(np.asarray(mua, np.float64))
    g = np.asarray(g, np.float64)
    channels, materials = mua.shape
    used = np.arange(materials) if used is None else np.asarray(used)
    mu_t = mus + mua
    walk_mu = mus + mua.min(axis=0)
    spread = mua.max(axis=0) - mua.min(axis=0)
    majorant = float(max(mu_t[:, used].max(), (walk_mu + spread / (1.0 - NULL_FACTOR_FLOOR))[used].max()))
    tables = np.zeros((MU_T + 2 * channels, materials))
    tables[WALK_MU] = walk_mu
    tables[SCATTER] = np.divide(mus, walk_mu, out=np.zeros(materials), where=walk_mu > 0)
    tables[ANISOTROPY] = g
    tables[MU_T:MU_T + channels] = mu_t
    room = majorant - walk_mu
    tables[MU_T + channels:] = np.divide(majorant - mu_t, room, out=np.ones_like(mu_t), where=room > 0)
    return tables, majorant


def single_channel_tables(mu_t: np.ndarray, albedo: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`walk_tables` of one channel given ``mu_t`` and ``albedo`` (M,) per material."""
    mu_t = np.asarray(mu_t, np.float64)
    mus = mu_t * np.asarray(albedo, np.float64)
    return walk_tables(mus, (mu_t - mus)[None], g)


@numba.njit(cache=True, inline="always")
def channel_count(tables):
    """How many channels a tables array serves."""
    return (tables.shape[0] - MU_T) // 2
