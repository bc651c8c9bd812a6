"""`diffblur synth`: blurred/sharp pairs for deblurring datasets (diffblur/app/synth.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")
from PIL import Image  # noqa: E402

from diffblur.app import synth  # noqa: E402
from diffblur.app.blur_image import read_picture  # noqa: E402
from diffblur.app.cli import main  # noqa: E402

QUIET = dict(highlight_gain=(1.0, 1.0), shot_noise=(0.0, 0.0), read_noise=(0.0, 0.0))


def _photos(folder, count=3, size=(24, 30)):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    for k in range(count):
        base = rng.random((6, 8, 3))
        pixels = np.kron(base, np.ones((size[0] // 6, size[1] // 8 + 1, 1)))[: size[0], : size[1]]
        Image.fromarray(np.round(255 * pixels).astype(np.uint8)).save(folder / f"photo{k}.png")
    return folder


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_same_seed_same_files_and_another_seed_other_motions(tmp_path):
    photos = _photos(tmp_path / "in")
    options = synth.SynthOptions(jpeg_quality=(60, 90))
    synth.synthesize_folder(photos, tmp_path / "a", seed=1, options=options, progress=False)
    synth.synthesize_folder(photos, tmp_path / "b", seed=1, options=options, progress=False)
    synth.synthesize_folder(photos, tmp_path / "c", seed=2, options=options, progress=False)
    assert _files(tmp_path / "a") == _files(tmp_path / "b")
    assert len(_files(tmp_path / "a")) == 9  # sharp, blurred, JSON per photograph
    motions = [json.loads((tmp_path / d / "photo0.json").read_text())["motion"] for d in "ac"]
    assert motions[0] != motions[1]


def test_the_json_reproduces_the_pair(tmp_path):
    photos = _photos(tmp_path / "in")
    records = synth.synthesize_folder(photos, tmp_path / "out", seed=5, options=synth.SynthOptions(motions=("pan", "shake"), jpeg_quality=(50, 95)), progress=False)
    assert {r["motion"]["kind"] for r in records} <= {"pan", "shake"}
    for record in records:
        sharp, blurred = synth.reproduce(tmp_path / "out" / (record["source"][:-4] + ".json"), photos)
        assert np.array_equal(sharp, np.asarray(Image.open(tmp_path / "out" / record["files"]["sharp"])))
        assert np.array_equal(blurred, np.asarray(Image.open(tmp_path / "out" / record["files"]["blurred"])))
        assert not np.array_equal(sharp, blurred)


def test_a_quiet_linear_camera_gives_the_photograph_and_its_gather_blur(tmp_path):
    import torch

    import torch_impl

    photos = _photos(tmp_path / "in", count=1)
    params = synth.draw_params(0, "photo0.png", synth.SynthOptions(motions=("pan",), response="linear", **QUIET))
    photo = read_picture(photos / "photo0.png")
    sharp, blurred = synth.synthesize(photo, params)
    assert np.array_equal(sharp, np.round(255 * photo).astype(np.uint8))
    velocity = torch.tensor(params["motion"]["velocity"], dtype=torch.float32).reshape(1, 2, 1, 1).expand(1, 2, *photo.shape[:2])
    speed = float(np.hypot(*params["motion"]["velocity"]))
    want = torch_impl.gather_blur(torch.tensor(photo.transpose(2, 0, 1)[None], dtype=torch.float32), velocity.contiguous(), samples=2 * int(np.ceil(speed)) + 1)
    assert np.array_equal(blurred, np.round(255 * np.clip(want[0].numpy().transpose(1, 2, 0), 0, 1)).astype(np.uint8))


def test_highlights_pass_white_before_the_blur_and_clip_after():
    photo = np.zeros((20, 40, 3))
    photo[:, 18:22] = 1.0  # a clipped vertical lamp
    params = synth.draw_params(0, "lamp.png", synth.SynthOptions(motions=("pan",), response="linear", **QUIET))
    params["motion"]["velocity"] = [6.0, 0.0]
    plain = synth.synthesize(photo, params)[1].astype(float)
    params["camera"]["highlight_gain"] = 4.0
    bright = synth.synthesize(photo, params)[1].astype(float)
    assert bright.sum() > 2 * plain.sum()  # the streak carries the lamp's real brightness
    assert bright.max() == 255 and plain[10, 20].max() < 255 * 0.5


def test_noise_follows_the_poisson_gaussian_model():
    photo = np.full((64, 64, 1), 0.5)
    params = synth.draw_params(0, "grey.png", synth.SynthOptions(motions=("pan",), response="linear", **QUIET))
    params["camera"].update(shot_noise=0.01, read_noise=0.02)
    blurred = synth.synthesize(photo, params)[1] / 255.0
    assert np.std(blurred) == pytest.approx(np.sqrt(0.01 * 0.5 + 0.02**2), rel=0.1)


def test_objects_move_by_label_over_a_still_background(tmp_path):
    photos = _photos(tmp_path / "in", count=2, size=(30, 36))
    masks = tmp_path / "masks"
    masks.mkdir()
    for k in range(2):
        label = np.zeros((30, 36), np.uint8)
        label[8:20, 10:22] = 200  # any label value: relabelled 1..n
        Image.fromarray(label).save(masks / f"photo{k}.png")
    options = synth.SynthOptions(motions=("objects",), length=(6.0, 10.0), **QUIET)
    records = synth.synthesize_folder(photos, tmp_path / "out", seed=3, options=options, segmentation=masks, progress=False)
    for record in records:
        assert record["motion"]["kind"] == "objects" and list(record["motion"]["labels"]) == ["1"]
        sharp, blurred = synth.reproduce(tmp_path / "out" / (record["source"][:-4] + ".json"), photos, segmentation=masks)
        assert np.array_equal(blurred, np.asarray(Image.open(tmp_path / "out" / record["files"]["blurred"])))
        if not any(record["motion"]["background"]):  # a still background stays sharp away from the object
            assert np.array_equal(blurred[:, 30:], sharp[:, 30:])
        assert not np.array_equal(blurred[8:20, 10:22], sharp[8:20, 10:22])


def test_a_sequence_blurs_each_frame_along_its_flows(tmp_path):
    frames = _photos(tmp_path / "in", count=2, size=(24, 30))
    flow = np.zeros((24, 30, 2), np.float32)
    flow[..., 0] = 3.0  # every pixel moves 3 px right per frame
    for k in range(2):
        synth.write_flo(frames / f"photo{k}.next.flo", flow)
        synth.write_flo(frames / f"photo{k}.prev.flo", -flow)
    options = synth.SynthOptions(response="linear", exposure=0.5, **QUIET)
    records = synth.synthesize_folder(frames, tmp_path / "out", seed=0, options=options, sequence=True, progress=False)
    for record in records:
        assert record["motion"] == {"kind": "objects", "flows": True, "exposure": 0.5}
        sharp, blurred = synth.reproduce(tmp_path / "out" / (record["source"][:-4] + ".json"), frames)
        assert np.array_equal(blurred, np.asarray(Image.open(tmp_path / "out" / record["files"]["blurred"])))
        # A uniform flow is a pan: rows blur along x only, so a column's mean changes little.
        photo = read_picture(frames / record["source"])
        assert np.abs(blurred[:, 4:-4].astype(float) / 255 - photo[:, 4:-4]).max() > 0.05
        assert np.allclose(blurred[:, 4:-4].astype(float).mean(axis=1) / 255, photo[:, 4:-4].mean(axis=1), atol=0.03)


def test_flo_round_trip_and_bad_files(tmp_path):
    flow = np.random.default_rng(0).normal(size=(5, 7, 2)).astype(np.float32)
    synth.write_flo(tmp_path / "f.flo", flow)
    assert np.array_equal(synth.read_flo(tmp_path / "f.flo"), flow)
    (tmp_path / "bad.flo").write_bytes(b"JUNK" + b"\0" * 12)
    with pytest.raises(ValueError, match="not a Middlebury .flo file"):
        synth.read_flo(tmp_path / "bad.flo")


def test_estimated_flow_follows_a_shift():
    pytest.importorskip("cv2", reason="the 'flow' extra (opencv-python-headless) is not installed")
    rng = np.random.default_rng(0)
    base = np.kron(rng.random((12, 16, 3)), np.ones((4, 4, 1)))
    shifted = np.roll(base, 2, axis=1)  # content moves 2 px right
    flow = synth.estimate_flow(base, shifted)
    assert np.median(flow[8:-8, 8:-8, 0]) == pytest.approx(2.0, abs=0.3)
    assert np.median(np.abs(flow[8:-8, 8:-8, 1])) < 0.3


def test_two_workers_write_what_one_does(tmp_path):
    photos = _photos(tmp_path / "in", count=2)
    synth.synthesize_folder(photos, tmp_path / "one", seed=4, progress=False)
    synth.synthesize_folder(photos, tmp_path / "two", seed=4, workers=2, progress=False)
    assert _files(tmp_path / "one") == _files(tmp_path / "two")


def test_command_line(tmp_path, capsys):
    photos = _photos(tmp_path / "in", count=2)
    assert main(["synth", str(photos), str(tmp_path / "out"), "--seed", "1", "--shutters", "box,tent", "--jpeg", "80", "90"]) == 0
    assert "wrote 2 pairs" in capsys.readouterr().out
    assert main(["synth", str(tmp_path / "missing"), str(tmp_path / "out")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert main(["synth", str(photos), str(tmp_path / "out"), "--motions", "objects"]) == 2
    assert "needs a segmentation picture or flow files" in capsys.readouterr().err
    assert main(["synth", str(photos), str(tmp_path / "out"), "--shutters", "sideways"]) == 2
    assert "shutter" in capsys.readouterr().err


def test_a_sequence_without_flow_files_estimates_them(tmp_path):
    pytest.importorskip("cv2", reason="the 'flow' extra (opencv-python-headless) is not installed")
    frames = tmp_path / "in"
    frames.mkdir()
    base = np.kron(np.random.default_rng(1).random((8, 10, 3)), np.ones((4, 4, 1)))
    for k in range(3):  # content moves 2 px right per frame
        Image.fromarray(np.round(255 * np.roll(base, 2 * k, axis=1)).astype(np.uint8)).save(frames / f"f{k}.png")
    records = synth.synthesize_folder(frames, tmp_path / "out", seed=0, options=synth.SynthOptions(**QUIET), sequence=True, estimate_flows=True, progress=False)
    assert [("skipped" in r) for r in records] == [True, False, True]  # the ends have one neighbour
    prev, nxt = (synth.read_flo(tmp_path / "out" / name) for name in records[1]["files"]["flows"])
    assert np.median(nxt[8:-8, 8:-8, 0]) == pytest.approx(2.0, abs=0.3)
    assert np.median(prev[8:-8, 8:-8, 0]) == pytest.approx(-2.0, abs=0.3)
    sharp, blurred = synth.reproduce(tmp_path / "out" / "f1.json", frames)
    assert np.array_equal(blurred, np.asarray(Image.open(tmp_path / "out" / "f1_blurred.png")))
