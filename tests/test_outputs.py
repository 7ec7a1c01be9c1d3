"""The output-writing rule (ringlight.core.atomic): an output replaces only files ringlight wrote
there, never deletes anything else, and every error names the user's path. Each writer of the
project (stack export, dataset writer, PNG, MP4, CSV/JSON text) is checked through it."""

import errno
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from reference import random_impulses, write_dataset
from ringlight.app.main import main
from ringlight.core import DatasetWriter, read_exr_rgb, read_stack, write_stack
from ringlight.core.atomic import OutputError, atomic_file
from ringlight.core.colour.image_export import write_movie, write_png, write_text
from ringlight.core.rings.stacks import Stack


def make_stack(count, value=1.0):
    images = np.full((count, 3, 4, 3), value, np.float32) + np.arange(count, dtype=np.float32)[:, None, None, None]
    return Stack(kind="ring", radii=np.arange(count, dtype=float), thickness=1.0, antialias=False,
                 colorspace="sRGB", images=images, counts=np.ones(images.shape[:3], np.int32))


def tree(folder):
    """Every file under ``folder`` (hidden ones too) with its bytes."""
    return {path.relative_to(folder).as_posix(): path.read_bytes()
            for path in sorted(Path(folder).rglob("*")) if path.is_file()}


def leftovers(folder):
    """Hidden temporaries of the rule anywhere under ``folder``."""
    return [path.name for path in Path(folder).rglob("*") if ".partial-" in path.name or ".old-" in path.name]


def one_line(capsys, *args):
    status = main([str(arg) for arg in args])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def dataset(tmp_path):
    write_dataset(tmp_path / "ds", 6, 5, random_impulses(np.random.default_rng(0), 6, 5, support=10))
    return tmp_path / "ds"


def test_a_stack_is_replaced_only_when_the_folder_holds_nothing_but_the_stack(tmp_path, dataset, capsys):
    out = tmp_path / "stack"
    write_stack(make_stack(3), out)
    (out / "thesis.tex").write_text("precious")
    before = tree(out)
    with pytest.raises(OutputError, match=r"stack: holds thesis.tex, which ringlight did not write"):
        write_stack(make_stack(2, 5.0), out)
    assert tree(out) == before and not leftovers(tmp_path)
    line = one_line(capsys, "stack", dataset, "--radii", "0:2:1", "--out", out)
    assert f"{out}: holds thesis.tex" in line and "move that file away or choose another folder" in line
    assert tree(out) == before
    # Without the foreign file the old export (3 images) is replaced whole by the new one (2).
    (out / "thesis.tex").unlink()
    write_stack(make_stack(2, 5.0), out)
    manifest, images = read_stack(out)
    assert sorted(tree(out)) == sorted(["stack.json", *manifest["images"]]) == ["ring_000.exr", "ring_001.exr",
                                                                                 "stack.json"]
    assert images[:, 0, 0, 0].tolist() == [5.0, 6.0]
    assert not leftovers(tmp_path)


def test_a_foreign_file_in_a_subfolder_or_an_empty_subfolder_is_foreign_too(tmp_path):
    out = tmp_path / "stack"
    write_stack(make_stack(1), out)
    (out / "figures").mkdir()
    with pytest.raises(OutputError, match="holds figures, which ringlight did not write"):
        write_stack(make_stack(1), out)
    assert (out / "figures").is_dir()


def test_the_current_folder_is_refused_with_one_line_and_nothing_left(tmp_path, dataset, monkeypatch, capsys):
    out = tmp_path / "here"
    write_stack(make_stack(2), out)
    before = tree(out)
    monkeypatch.chdir(out)
    line = one_line(capsys, "stack", dataset, "--radii", "0:2:1", "--out", ".")
    assert line == ("ringlight: error: .: is the current folder (or holds it); ringlight publishes a stack by "
                    "renaming a new folder into place, so write it to a new folder, e.g. stack")
    with pytest.raises(OutputError, match="is the current folder"):
        write_stack(make_stack(2), tmp_path)  # a folder holding the current folder
    assert tree(out) == before and not leftovers(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    with pytest.raises(OutputError, match="is the current folder"):
        DatasetWriter(".", (2, 2))
    # The suggested folder inside works.
    write_stack(make_stack(1), "stack")
    assert read_stack(empty / "stack")[1].shape == (1, 3, 4, 3)


def test_a_stack_whose_images_differ_in_size_is_one_line_naming_the_image(tmp_path):
    """An edited stack folder whose second image is another size: read_stack names that file and
    both sizes (numpy's stack raised a ValueError before)."""
    from ringlight.core.dataset.exr import write_exr_rgb
    from ringlight.core.errors import DatasetError
    write_stack(make_stack(2), tmp_path / "stack")
    name = json.loads((tmp_path / "stack" / "stack.json").read_text())["images"][1]
    (tmp_path / "stack" / name).unlink()
    write_exr_rgb(tmp_path / "stack" / name, np.zeros((5, 6, 3), np.float32))
    with pytest.raises(DatasetError) as refused:
        read_stack(tmp_path / "stack")
    assert str(refused.value).startswith(f"{tmp_path / 'stack' / name}: 6 x 5 pixels, where the stack's first image")
    assert str(refused.value).endswith("has 4 x 3")


def test_a_dangling_link_is_refused_and_a_link_to_a_stack_keeps_pointing_at_it(tmp_path):
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "missing" / "target")
    for write in (lambda: write_stack(make_stack(1), link), lambda: DatasetWriter(link, (2, 2))):
        with pytest.raises(OutputError) as refused:
            write()
        assert str(refused.value) == (f"{link}: is a symbolic link to {tmp_path}/missing/target, which does not "
                                      "exist; create that folder or give another path")
    assert not (tmp_path / "missing").exists() and link.is_symlink()
    real = tmp_path / "real"
    write_stack(make_stack(2), real)
    link.unlink()
    link.symlink_to(real)
    write_stack(make_stack(1, 7.0), link)
    assert link.is_symlink() and read_stack(real)[1][:, 0, 0, 0].tolist() == [7.0]
    assert not leftovers(tmp_path)


def read_only(folder, monkeypatch):
    """Make ``folder`` read-only for the writers; root ignores permission bits, so there the
    refusal the kernel would give (EACCES naming the hidden temporary) is raised by os.mkdir
    and open instead."""
    folder.chmod(0o555)
    if os.geteuid() != 0:
        return
    import builtins
    import io

    def refuse(name):
        if Path(name).parent == folder:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(name))

    real_mkdir, real_open = os.mkdir, io.open

    def fake_open(name, *args, **kwargs):
        if isinstance(name, (str, os.PathLike)):
            refuse(name)
        return real_open(name, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", lambda name, *a, **k: refuse(name) or real_mkdir(name, *a, **k))
    monkeypatch.setattr(io, "open", fake_open)
    monkeypatch.setattr(builtins, "open", fake_open)


def test_errors_on_a_read_only_folder_name_the_users_path_not_a_temporary(tmp_path, monkeypatch):
    locked = tmp_path / "locked"
    locked.mkdir()
    read_only(locked, monkeypatch)
    try:
        for write, shown in [(lambda: write_stack(make_stack(1), locked / "stack"), locked / "stack"),
                             (lambda: DatasetWriter(locked / "ds", (2, 2)).__enter__(), locked / "ds"),
                             (lambda: write_text(locked / "layers.json", "{}"), locked / "layers.json")]:
            with pytest.raises(OutputError) as refused:
                write()
            assert str(refused.value) == (f"{shown}: cannot write here: Permission denied "
                                          "(the folder is read-only for you)")
    finally:
        locked.chmod(0o755)
    assert list(locked.iterdir()) == []


def test_a_failed_write_inside_an_output_names_the_users_file(tmp_path, monkeypatch):
    from ringlight.core.rings import stack_io

    def disk_full(path, image):
        # What the OpenEXR library raises when the disk fills (measured on a 64 KiB tmpfs).
        raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')

    monkeypatch.setattr(stack_io, "write_exr_rgb", disk_full)
    with pytest.raises(OutputError) as failed:
        write_stack(make_stack(1), tmp_path / "stack")
    assert str(failed.value) == (f'Failed to write pixel data to image file "{tmp_path}/stack/ring_000.exr". '
                                 "No space left on device.")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kind", ["png", "text", "movie"])
def test_single_files_are_never_overwritten_without_the_explicit_flag(tmp_path, kind):
    path = tmp_path / {"png": "a.png", "text": "a.csv", "movie": "a.mp4"}[kind]
    pixels = np.full((4, 6, 3), 200, np.uint8)
    write = {"png": lambda **flag: write_png(path, pixels, **flag),
             "text": lambda **flag: write_text(path, "new", **flag),
             "movie": lambda **flag: write_movie(path, [pixels].__getitem__, ["r = 0"], 5.0, **flag)}[kind]
    path.write_bytes(b"user data")
    with pytest.raises(OutputError, match=r"a\.\w+: already exists; refusing to overwrite it"):
        write()
    assert path.read_bytes() == b"user data" and sorted(tmp_path.iterdir()) == [path]
    write(overwrite=True)
    assert path.read_bytes() != b"user data" and sorted(tmp_path.iterdir()) == [path]
    if kind == "text":
        assert path.read_text() == "new"


def test_a_dangling_link_or_a_folder_in_place_of_a_file_is_refused(tmp_path):
    link = tmp_path / "out.json"
    link.symlink_to(tmp_path / "elsewhere.json")
    with pytest.raises(OutputError, match="out.json: already exists"):
        write_text(link, "{}")
    (tmp_path / "folder.csv").mkdir()
    with pytest.raises(OutputError, match="folder.csv: is a folder; give a file name"):
        write_text(tmp_path / "folder.csv", "x", overwrite=True)
    assert not (tmp_path / "elsewhere.json").exists() and link.is_symlink()


def test_a_file_that_appears_while_another_is_written_is_never_replaced(tmp_path):
    path = tmp_path / "a.json"
    with pytest.raises(OutputError, match="appeared while it was written"):
        with atomic_file(path) as temporary:
            temporary.write_text("ours")
            path.write_text("theirs")
    assert path.read_text() == "theirs" and sorted(tmp_path.iterdir()) == [path]


def test_a_device_or_a_fifo_is_never_replaced_even_with_force(tmp_path, dataset, capsys):
    """``--force`` renamed a file over ``/dev/null`` (as root: the system's null device became a
    3 KB JSON file) and over a FIFO: something that is neither a file nor a link is refused, with
    or without overwriting, before any work."""
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    for overwrite in (False, True):
        with pytest.raises(OutputError, match="fifo.json: is not a file .a device, a FIFO or a socket.; refusing"):
            write_text(fifo, "{}", overwrite=overwrite)
    # (A FIFO, not /dev/null itself: were the check broken, the suite would replace the machine's.)
    line = one_line(capsys, "layers", dataset, "--radii", "0,1", "--json", fifo, "--force")
    assert line == (f"ringlight: error: {fifo}: is not a file (a device, a FIFO or a socket); refusing to replace "
                    "it; give a file name")
    assert fifo.is_fifo()


def test_a_result_is_never_written_over_the_dataset_it_is_computed_from(tmp_path, dataset, capsys):
    """``layers DATASET --json DATASET/dataset.json --force`` wrote its result over the manifest (the
    dataset was lost, exit 0); the same for a frame, and anything in ringlight's store. A new file
    in the dataset's folder is still written."""
    before = tree(dataset)
    frame = json.loads((dataset / "dataset.json").read_text())["frames"][0]["file"]
    for target in (dataset / "dataset.json", dataset / frame, dataset / ".ringlight-cache" / "notes.json"):
        line = one_line(capsys, "layers", dataset, "--radii", "0,1", "--json", target, "--force")
        assert line == (f"ringlight: error: {target}: is a file of the dataset {dataset} that this command reads; "
                        "refusing to replace it; write elsewhere")
    assert tree(dataset) == before
    assert main(["layers", str(dataset), "--radii", "0,1", "--json", str(dataset / "layers.json")]) == 0
    assert json.loads((dataset / "layers.json").read_text())["radii"] == [0, 1]


def test_the_optics_outputs_are_checked_together_before_the_work(tmp_path, dataset, capsys):
    """Two outputs naming one file wrote the maps and then refused the JSON (or, with --force,
    replaced the maps by it); maps named .png were an EXR under that name."""
    same = tmp_path / "same.exr"
    line = one_line(capsys, "optics", dataset, "--out", same, "--json", same, "--force")
    assert line == f"ringlight: error: {same}, {same}: two outputs name the same file; give each its own"
    line = one_line(capsys, "optics", dataset, "--out", tmp_path / "maps.png")
    assert line == (f"ringlight: error: {tmp_path / 'maps.png'}: the maps are written as OpenEXR: "
                    "give a name ending in .exr")
    line = one_line(capsys, "optics", dataset, "--json", dataset / "dataset.json", "--force")
    assert line == (f"ringlight: error: {dataset / 'dataset.json'}: is a file of the dataset {dataset} that this "
                    "command reads; refusing to replace it; write elsewhere")
    assert not same.exists() and sorted(path.name for path in tmp_path.iterdir()) == ["ds"]


def test_the_layers_command_refuses_an_existing_json_file(tmp_path, dataset, capsys):
    existing = tmp_path / "layers.json"
    existing.write_text("thesis data")
    line = one_line(capsys, "layers", dataset, "--radii", "0,1", "--json", existing)
    assert f"{existing}: already exists; refusing to overwrite it" in line
    assert existing.read_text() == "thesis data"


def write_small_dataset(path, value, frames=2, **options):
    with DatasetWriter(path, (2, 2), **options) as writer:
        for index in range(frames):
            writer.add_frame(np.full((2, 2, 3), value, np.float32), lit=[[index // 2, index % 2]])


def test_overwriting_a_dataset_keeps_foreign_files_and_replaces_only_the_datasets(tmp_path, capsys):
    out = tmp_path / "ds"
    write_small_dataset(out, 1.0, frames=4)
    (out / ".ringlight-cache").mkdir()
    (out / ".ringlight-cache" / "meta.json").write_text("{}")
    (out / "notes.txt").write_text("lab notebook")
    before = tree(out)
    with pytest.raises(OutputError, match=r"ds: holds notes.txt, which ringlight did not write"):
        write_small_dataset(out, 3.0, overwrite=True)
    line = one_line(capsys, "simulate", "homogeneous", "--size", "4x4", "--photons", "10", "--out", out,
                    "--overwrite")
    assert f"{out}: holds notes.txt, which ringlight did not write" in line
    assert tree(out) == before and not leftovers(tmp_path)
    with pytest.raises(OutputError, match=r"ds: already holds a dataset; refusing to overwrite it \(pass overwrite"):
        write_small_dataset(out, 3.0)
    # The dataset's own files, ringlight's cache and hidden temporaries are all it holds now.
    (out / "notes.txt").unlink()
    (out / ".frames.partial-0123456789ab").mkdir()
    write_small_dataset(out, 3.0, overwrite=True)
    assert sorted(tree(out)) == ["dataset.json", "frames/000000.exr", "frames/000001.exr"]
    assert read_exr_rgb(out / "frames/000001.exr")[0, 0, 0] == 3.0
    assert not leftovers(tmp_path)


@pytest.mark.parametrize("name", [".thesis.partial-0123456789ab.tex", ".notes.old-0123456789ab",
                                  "frames/.figure.partial-abcdef012345.png"])
def test_a_users_file_named_like_a_temporary_is_never_taken_for_ringlights(tmp_path, name):
    """A hidden temporary is ringlight's only when what it stands for is (found by a fuzz campaign:
    a user's ``.thesis.partial-HEX.tex`` in an old output was deleted when it was replaced)."""
    out = tmp_path / "ds"
    write_small_dataset(out, 1.0)
    (out / name).parent.mkdir(exist_ok=True)
    (out / name).write_text("precious")
    before = tree(out)
    with pytest.raises(OutputError, match=rf"ds: holds {re.escape(name)}, which ringlight did not write"):
        write_small_dataset(out, 3.0, overwrite=True)
    assert tree(out) == before and (out / name).read_text() == "precious"
    # ringlight's own temporaries (of a frame, of the manifest, of the cache) are still its own
    (out / name).unlink()
    for temporary in ("frames/.000001.partial-0123456789ab.exr", ".dataset.partial-abcdef012345.json",
                      "..ringlight-cache.partial-0123456789ab/meta.json"):
        (out / temporary).parent.mkdir(exist_ok=True)
        (out / temporary).write_text("torn")
    write_small_dataset(out, 3.0, overwrite=True)
    assert sorted(tree(out)) == ["dataset.json", "frames/000000.exr", "frames/000001.exr"]


def test_a_file_dropped_into_the_target_while_a_dataset_is_written_stops_the_replacement(tmp_path):
    out = tmp_path / "ds"
    write_small_dataset(out, 1.0)
    before = tree(out)
    with pytest.raises(OutputError, match="holds late.txt, which ringlight did not write"):
        with DatasetWriter(out, (2, 2), overwrite=True) as writer:
            writer.add_frame(np.zeros((2, 2, 3)), lit=[[0, 0]])
            (out / "late.txt").write_text("arrived during the write")
    assert tree(out) == {**before, "late.txt": b"arrived during the write"} and not leftovers(tmp_path)


def test_a_foreign_manifest_that_names_outside_files_owns_nothing_outside(tmp_path):
    out = tmp_path / "stack"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    (out / "stack.json").write_text(json.dumps({"format": "ringlight-stack", "images": [
        "../stack/thesis.tex", str(out / "thesis.tex"), "./thesis.tex"]}))
    with pytest.raises(OutputError, match="holds thesis.tex"):
        write_stack(make_stack(1), out)
    assert (out / "thesis.tex").read_text() == "precious"


def test_a_link_planted_in_place_of_a_private_folder_is_replaced_not_followed(tmp_path):
    from ringlight.core.atomic import atomic_folder

    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "thesis.tex").write_text("precious")
    cache = tmp_path / "ds" / ".ringlight-cache"
    cache.parent.mkdir()
    cache.symlink_to(thesis)
    with atomic_folder(cache) as staging:
        (staging / "meta.json").write_text("{}")
    assert not cache.is_symlink() and sorted(tree(cache)) == ["meta.json"]
    assert tree(thesis) == {"thesis.tex": b"precious"}


def test_a_link_planted_at_a_private_folders_name_as_its_path_is_resolved_is_never_followed(tmp_path, monkeypatch):
    """A hostile process plants a link to the user's folder at a cache entry's name at the moment
    the writer resolves the entry's path (after the writer removed any link there): the user's
    folder must keep its files, and the entry is written in the link's place (a fuzz campaign's
    race: the link was resolved, and the user's folder replaced by the cache entry)."""
    from ringlight.core.atomic import atomic_folder

    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "thesis.tex").write_text("precious")
    entry = tmp_path / "cache" / "entry"
    entry.parent.mkdir()
    resolve = os.path.realpath

    def plant_then_resolve(path, *args, **kwargs):
        if not entry.is_symlink():
            entry.symlink_to(thesis)
        return resolve(path, *args, **kwargs)

    monkeypatch.setattr(os.path, "realpath", plant_then_resolve)
    with atomic_folder(entry) as staging:
        (staging / "meta.json").write_text("{}")
    monkeypatch.undo()
    assert tree(thesis) == {"thesis.tex": b"precious"}
    assert not entry.is_symlink() and sorted(tree(entry)) == ["meta.json"]
    assert sorted(path.name for path in entry.parent.iterdir()) == ["entry"]  # the link removed, not left hidden


@pytest.mark.skipif(not Path("/proc/version").exists(), reason="needs Linux's /proc, a folder no one can write")
def test_an_output_file_in_a_folder_that_cannot_be_written_is_refused_before_the_work(tmp_path, capsys):
    """`layers --json /proc/version --force` computed the whole fit, then failed to write (found by
    a user review): the folder is now probed first, and the probe leaves nothing behind."""
    from ringlight.core.atomic import check_output_file

    assert main(["layers", str(tmp_path / "absent"), "--json", "/proc/version", "--force"]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and error[0].startswith("ringlight: error: /proc/version: cannot write here")
    check_output_file(tmp_path / "out.json", probe=True)
    assert list(tmp_path.iterdir()) == []


def test_a_folder_output_under_a_file_is_refused_before_the_work(tmp_path, dataset, capsys, monkeypatch):
    """``stack DATASET --out notes.txt/x`` computed the stack, then said "cannot write here: File
    exists"; every folder output (stacks, datasets, scans) now names the file first."""
    (tmp_path / "notes.txt").write_text("mine")
    monkeypatch.chdir(tmp_path)
    line = one_line(capsys, "stack", dataset, "--radii", "0:1:1", "--out", "notes.txt/x")
    assert line == "ringlight: error: notes.txt/x: notes.txt is a file, not a folder; give another path"
    assert (tmp_path / "notes.txt").read_text() == "mine" and not leftovers(tmp_path)
