"""Files written whole (lobelight._io): concurrent writers and readers of one path."""

from __future__ import annotations

import builtins
import io as io_module
import os
import stat
import subprocess
import sys
import textwrap

import pytest

from lobelight import _io, model

#: Each writer writes whole files of one repeated byte; a torn or mixed file has two values.
_WRITER = textwrap.dedent(
    """
    import sys
    from lobelight._io import atomic_writer
    path, byte, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    block = bytes([byte]) * (1 << 18)
    for _ in range(count):
        with atomic_writer(path) as f:
            for _ in range(4):  # 1 MiB in four writes: a reader could catch it half done
                f.write(block)
    """
)


def test_two_processes_writing_one_path_leave_one_whole_file(tmp_path):
    """Two processes rewrite the same 1 MiB file 40 times each while this one reads it: every
    read and the file left at the end are one writer's whole file, and no temporary file is
    left (with a plain open-and-write the reads tear and the bytes mix)."""
    target = tmp_path / "model.npz"
    writers = [
        subprocess.Popen([sys.executable, "-c", _WRITER, str(target), str(b), "40"]) for b in (1, 2)
    ]
    reads = 0
    while any(w.poll() is None for w in writers):
        try:
            data = target.read_bytes()
        except FileNotFoundError:  # not written yet
            continue
        assert len(data) == 1 << 20 and len(set(data)) == 1, "a reader saw a partial file"
        reads += 1
    assert [w.wait() for w in writers] == [0, 0]
    data = target.read_bytes()
    assert len(data) == 1 << 20 and set(data) in ({1}, {2})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]
    assert reads > 0


#: Saves one model (a tiny sphere whose light depends on ``tag``) ``count`` times.
_SAVER = textwrap.dedent(
    """
    import sys
    from lobelight.bench import synthetic_model
    path, tag, count = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
    m = synthetic_model(40, 1)
    m.diffuse[:, 0] = tag
    print("ready", flush=True)
    for _ in range(count):
        m.save(path)
    """
)


def test_two_processes_saving_one_model_200_times_each(tmp_path):
    """The concurrent-writers reproducer with models: two processes save to one path 200 times
    each while this one loads it. Every save succeeds, every load gives one writer's whole
    model, and nothing but the model is left (fixed temporary names crashed saves and tore
    reads)."""
    target = tmp_path / "m.npz"
    savers = [
        subprocess.Popen(
            [sys.executable, "-c", _SAVER, str(target), tag, "200"], stdout=subprocess.PIPE
        )
        for tag in ("0.25", "0.75")
    ]
    for s in savers:  # both started before the race is watched
        assert s.stdout.readline().strip() == b"ready"
    loads = set()
    while any(s.poll() is None for s in savers):
        if target.exists():
            loads.add(round(float(model.load(target).diffuse[0, 0, 0]), 4))
    assert [s.wait() for s in savers] == [0, 0]
    assert loads <= {0.25, 0.75} and loads
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz"]


def test_an_error_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "image.png"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError), _io.atomic_path(target) as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path  # writers pick by extension
        tmp.write_bytes(b"half of the new")
        raise RuntimeError("interrupted")
    assert target.read_bytes() == b"old"
    assert sorted(tmp_path.iterdir()) == [target]


def test_a_written_file_has_the_usual_permissions(tmp_path):
    """mkstemp makes owner-only files; a written file gets what a plain open would give."""
    mask = os.umask(0o022)
    try:
        with _io.atomic_writer(tmp_path / "sub" / "x.json") as f:
            f.write(b"{}")
    finally:
        os.umask(mask)
    mode = stat.S_IMODE((tmp_path / "sub" / "x.json").stat().st_mode)
    assert mode == 0o644


def test_reading_an_input_asks_for_memory_by_the_file_not_the_limit(tmp_path, monkeypatch):
    """A read of n bytes allocates n bytes at once: reading a 1 kB map with f.read(4 GiB + 1)
    asked for 4 GiB (the fuzz run's memory limit caught it on every map). Reads are sized by
    the file, and a file that grows while it is read is still refused at the limit."""
    asked = []

    class Recording(io_module.BufferedReader):
        def read(self, n=-1):
            asked.append(n)
            return super().read(n)

    real_open = builtins.open
    monkeypatch.setattr(
        builtins, "open", lambda p, mode="r", *a, **k: Recording(real_open(p, "rb", buffering=0))
    )
    p = tmp_path / "map.hdr"
    real_open(p, "wb").write(bytes(1000))
    assert _io.read_input(p, limit=4 << 30) == bytes(1000)
    assert asked[0] == 1001 and max(asked) <= 1 << 20  # then MiB steps to see the end
