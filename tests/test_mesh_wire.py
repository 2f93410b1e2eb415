"""The reference decoder (resecta_client.wire, clients/python) against golden messages of the Rust encoder
(server/crates/engine/resecta-delta/tests/golden.rs): bit-identical to what Rust decodes, within
the quantisation bounds of what was encoded, and ValueError on truncated or corrupted input."""

import json
import os
import re
import shutil
import struct
import subprocess
import sys
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zstandard

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "clients" / "python" / "src"))  # until the venv installs it
from resecta_client import wire as mw  # noqa: E402
NORMAL_BOUND_RAD = 5e-5  # stated octahedral bound (resecta_delta::Quantise::normals)
ATTRS = (
    ("positions", "positions"),
    ("normals", "normals"),
    ("margin", "margins"),
    ("classes", "classes"),
)


@pytest.fixture(scope="module")
def golden(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    if shutil.which("cargo") is None:
        print("SKIP: cargo not on PATH, cannot build the golden messages")
        pytest.skip("cargo not on PATH")
    out = tmp_path_factory.mktemp("golden")
    proc = subprocess.run(
        ["cargo", "test", "-p", "resecta-delta", "--test", "golden", "--locked"],
        check=False,
        cwd=ROOT,
        env={**os.environ, "RESECTA_DELTA_GOLDEN_DIR": str(out)},
        capture_output=True,
        text=True,
        timeout=3600,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out, json.loads((out / "expected.json").read_text())


def cases(golden: tuple[Path, dict[str, Any]], kind: str) -> list[dict[str, Any]]:
    found = [c for c in golden[1]["cases"] if c["kind"] == kind]
    assert found
    return found


def read(golden: tuple[Path, dict[str, Any]], name: str) -> bytes:
    return (golden[0] / name).read_bytes()


def bits(a: np.ndarray | None) -> list[Any] | None:
    return None if a is None else a.view(np.uint32 if a.dtype == np.float32 else a.dtype).tolist()


def assert_same(got: Mapping[str, Any], want: dict[str, Any], name: str) -> None:
    """Bitwise equal to the Rust decoder's frame (absent attributes are None here, empty there)."""
    for key, wkey in ATTRS:
        w = want[wkey]
        assert bits(got[key]) == (w if w or key == "positions" else None), f"{name}: {key}"


def assert_close(
    got: Mapping[str, Any], src: dict[str, Any], case: dict[str, Any], rows: list[int]
) -> None:
    """Within half a quantisation step (+ an f32 ulp) and the octahedral bound of the encoded
    frame where quantised, else bitwise equal, on `rows`."""
    f = case["value_flags"]  # the encodings the values went through (a delta's or its base's)
    pos = np.array(src["positions"], np.uint32).reshape(-1, 3).view(np.float32)[rows]
    g = got["positions"][rows]
    if f & mw.POSITIONS_U16:
        step = np.array(case["position_step"], np.float64)
        err = np.abs(g.astype(np.float64) - pos)
        ok = (err <= 0.5 * step + np.spacing(np.abs(pos))) | (~np.isfinite(pos) & np.isnan(g))
        assert ok.all(), case["file"]
    else:
        assert g.view(np.uint32).tolist() == pos.view(np.uint32).tolist(), case["file"]
    if src["normals"]:
        nrm = np.array(src["normals"], np.uint32).reshape(-1, 3).view(np.float32)[rows]
        g = got["normals"][rows]
        if f & mw.NORMALS_OCT16:
            a, b = g.astype(np.float64), nrm.astype(np.float64)
            angle = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))
            zero = ~nrm.any(axis=1)
            assert (g[zero] == 0).all(), case["file"]
            assert (angle[~zero] <= NORMAL_BOUND_RAD).all(), case["file"]
        else:
            assert g.view(np.uint32).tolist() == nrm.view(np.uint32).tolist(), case["file"]
    if src["margins"]:  # never quantised
        assert got["margin"][rows].view(np.uint32).tolist() == [src["margins"][i] for i in rows]
    if src["classes"]:
        assert got["classes"][rows].tolist() == [src["classes"][i] for i in rows]


def test_meshes_decode_like_rust_and_within_bounds(golden: Any) -> None:
    for case in cases(golden, "mesh"):
        buf = read(golden, case["file"])
        m = mw.decode_mesh(buf)
        h = case["header"]
        assert (
            m["version"],
            m["flags"],
            m["vertex_count"],
            m["triangle_count"],
            m["payload_bytes"],
        ) == (h["version"], h["flags"], h["vertex_count"], h["count2"], h["payload_bytes"])
        assert m["triangles"].dtype == np.uint32 and m["triangles"].tolist() == case["triangles"]
        assert m["positions"].dtype == np.float32 and m["positions"].shape == (h["vertex_count"], 3)
        assert_same(m, case["decoded"], case["file"])
        assert_close(m, case["source"], case, list(range(h["vertex_count"])))
        assert bool(h["flags"] & mw.ZSTD) == ("zstd" in case["file"])


def test_deltas_apply_like_rust_and_within_bounds(golden: Any) -> None:
    for case in cases(golden, "delta"):
        buf = read(golden, case["file"])
        d = mw.decode_delta(buf)
        assert d["changed"].tolist() == case["changed"]
        assert (d["flags"], d["vertex_count"], d["changed_count"]) == (
            case["header"]["flags"],
            case["header"]["vertex_count"],
            case["header"]["count2"],
        )
        base = mw.decode_mesh(read(golden, case["base"]))
        held: Mapping[str, Any] = base
        before = {k: bits(held[k]) for k, _ in ATTRS}
        after = mw.apply_delta(base, buf)
        assert {k: bits(held[k]) for k, _ in ATTRS} == before, "apply_delta modified its input"
        assert after["triangles"].tolist() == base["triangles"].tolist()
        assert_same(after, case["decoded"], case["file"])
        assert_close(after, case["source"], case, case["changed"])
        # In place: the same values, written into the held arrays themselves.
        positions = base["positions"]
        assert mw.apply_delta(base, buf, in_place=True) is base and base["positions"] is positions
        assert_same(base, case["decoded"], case["file"])


def uncompressed(buf: bytes) -> bytes:
    """The same message without zstd (flag cleared, payload decompressed)."""
    flags = struct.unpack_from("<H", buf, 6)[0]
    assert flags & mw.ZSTD
    payload = zstandard.ZstdDecompressor().decompress(buf[20:])
    return buf[:6] + struct.pack("<H", flags & ~mw.ZSTD) + buf[8:20] + payload


def test_zstd_is_only_framing(golden: Any) -> None:
    for case in golden[1]["cases"]:
        if case["header"]["flags"] & mw.ZSTD:
            buf = read(golden, case["file"])
            if case["kind"] == "mesh":
                assert bits(mw.decode_mesh(uncompressed(buf))["positions"]) == bits(
                    mw.decode_mesh(buf)["positions"]
                )
            else:
                assert mw.decode_delta(uncompressed(buf))["changed"].tolist() == case["changed"]


def patched(buf: bytes, at: int, fmt: str, value: int) -> bytes:
    b = bytearray(buf)
    struct.pack_into(fmt, b, at, value)
    return bytes(b)


def test_truncated_and_corrupted_messages_raise_value_error(golden: Any) -> None:
    g = golden
    for case in g[1]["cases"]:
        buf = read(g, case["file"])
        decode: Callable[[bytes], object] = mw.decode_mesh
        if case["kind"] == "delta":
            base = mw.decode_mesh(read(g, case["base"]))
            decode = partial(mw.apply_delta, base)
        for cut in sorted({0, 3, 19, 20, 21, len(buf) // 2, len(buf) - 1}):
            if cut < len(buf):
                with pytest.raises(ValueError):
                    decode(buf[:cut])
        for bad in [
            buf + b"\0",
            b"RSXX" + buf[4:],
            patched(buf, 4, "<H", mw.VERSION - 1),  # version
            patched(buf, 4, "<H", mw.VERSION + 1),
            patched(buf, 6, "<H", case["header"]["flags"] | 0x100),  # reserved flag bit
            patched(buf, 16, "<I", case["header"]["payload_bytes"] + 4),
            patched(buf, 8, "<I", case["header"]["vertex_count"] + 1),
            patched(buf, 12, "<I", case["header"]["count2"] + 1),
            patched(buf, 12, "<I", 0xFFFFFFFF),
            patched(buf, 8, "<I", 0xFFFFFFFF),
        ]:
            with pytest.raises(ValueError):
                decode(bad)
        with pytest.raises(ValueError, match="expected"):
            (mw.decode_delta if case["kind"] == "mesh" else mw.decode_mesh)(buf)

    mesh = read(g, "mesh_exact.rsms")
    with pytest.raises(ValueError, match="triangle 2 refers to vertex 144"):
        mw.decode_mesh(patched(mesh, 20 + 2 * 12 + 8, "<I", 144))
    with pytest.raises(ValueError, match="a mesh has positions"):
        mw.decode_mesh(patched(mesh, 6, "<H", (0x0F | mw.INDEX_LIST)))
    with pytest.raises(ValueError, match="zstd"):
        z = bytearray(read(g, "mesh_exact_zstd.rsms"))
        z[20] ^= 0xFF  # the frame's magic number
        mw.decode_mesh(bytes(z))

    bare_msg = read(g, "mesh_bare_quant.rsms")  # positions only, quantised
    with pytest.raises(ValueError, match="NORMALS_OCT16 without a normals section"):
        flags = struct.unpack_from("<H", bare_msg, 6)[0]
        mw.decode_mesh(patched(bare_msg, 6, "<H", flags | mw.NORMALS_OCT16))

    few = read(g, "delta_few_exact.rsdl")  # index list [0, 17, 143]
    with pytest.raises(ValueError, match="POSITIONS_U16 without a positions section"):
        mw.decode_delta(patched(few, 6, "<H", mw.POSITIONS_U16 | mw.MARGINS | mw.CLASSES | mw.INDEX_LIST))
    with pytest.raises(ValueError, match="ascending"):
        mw.decode_delta(patched(few, 24, "<I", 0))
    with pytest.raises(ValueError, match="ascending"):
        mw.decode_delta(patched(few, 28, "<I", 144))
    band = uncompressed(read(g, "delta_band_exact_zstd.rsdl"))  # bitmap of 5 words, 144 vertices
    with pytest.raises(ValueError, match="bit 150 set beyond"):
        mw.decode_delta(patched(band, 20 + 16, "<I", 1 << 22))
    with pytest.raises(ValueError, match="bits set"):
        mw.decode_delta(patched(band, 20, "<I", 1))

    quant = mw.decode_mesh(read(g, "mesh_quant.rsms"))
    bare = mw.decode_mesh(read(g, "mesh_bare_quant.rsms"))
    with pytest.raises(ValueError, match="vertex count differs"):
        mw.apply_delta(mw.decode_mesh(read(g, "mesh_empty.rsms")), few)
    with pytest.raises(ValueError, match="normals present in the delta"):
        mw.apply_delta(bare, read(g, "delta_all_quant_zstd.rsdl"))
    with pytest.raises(ValueError):
        mw.apply_delta(quant, mesh)


def test_zstd_frames_carry_a_checksum_that_is_verified(golden: Any) -> None:
    compressed = [c for c in golden[1]["cases"] if c["header"]["flags"] & mw.ZSTD]
    assert len(compressed) >= 3
    for case in compressed:
        buf = read(golden, case["file"])
        frame = buf[20:]
        assert zstandard.get_frame_parameters(frame).has_checksum, case["file"]
        decode: Callable[[bytes], object] = mw.decode_mesh
        if case["kind"] == "delta":
            decode = partial(mw.apply_delta, mw.decode_mesh(read(golden, case["base"])))
        bad = bytearray(buf)
        bad[-1] ^= 0x5A  # the checksum itself
        with pytest.raises(ValueError, match="checksum does not match"):
            decode(bytes(bad))
        payload = zstandard.ZstdDecompressor().decompress(frame)
        plain = zstandard.ZstdCompressor(level=3, write_checksum=False).compress(payload)
        with pytest.raises(ValueError, match="no content checksum"):
            decode(buf[:20] + plain)
        with pytest.raises(ValueError):
            decode(buf + frame)  # two frames
        # Any single flipped bit in the frame: a ValueError, or exactly what the intact message
        # decodes to (never other data of the right length).
        want = decode(buf)
        for at in range(20, len(buf)):
            for bit in (0x01, 0x80):
                b = bytearray(buf)
                b[at] ^= bit
                try:
                    got = decode(bytes(b))
                except ValueError:
                    continue
                for key, _ in ATTRS:
                    assert bits(got[key]) == bits(want[key]), (case["file"], at, bit)  # type: ignore[index]


def test_random_corruption_never_raises_anything_but_value_error(golden: Any) -> None:
    rng = np.random.default_rng(7)
    for case in golden[1]["cases"]:
        buf = read(golden, case["file"])
        decode = mw.decode_mesh if case["kind"] == "mesh" else mw.decode_delta
        for _ in range(300):
            b = bytearray(buf)
            for at in rng.integers(0, len(b), rng.integers(1, 4)):
                b[at] ^= int(rng.integers(1, 256))
            try:
                decode(bytes(b))
            except ValueError:
                pass


def test_the_browser_decoder_matches_rust_on_every_golden_message(golden):
    """The TypeScript decoder of the browser client (web/src/wire.ts), run by Node on the same
    golden messages: its own test compares headers, triangles and bit patterns with Rust's."""
    web = ROOT / "web"
    if shutil.which("npm") is None or not (web / "node_modules").is_dir():
        print("SKIP: npm or web/node_modules missing (scripts/test.sh installs them)")
        pytest.skip("web/node_modules missing")
    proc = subprocess.run(["npm", "test", "--silent"], cwd=web, capture_output=True, text=True,
                          env={**os.environ, "RESECTA_GOLDEN_DIR": str(golden[0])}, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    assert "RESECTA_GOLDEN_DIR is not set" not in out, out[-2000:]
    ran = re.search(r"^\s*ok \d+ - meshes decode like Rust\s*$", out, re.MULTILINE)
    assert ran and "# fail 0" in out, out[-2000:]
