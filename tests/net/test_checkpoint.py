"""The checkpoint check every network-reading stage runs first (expoctl.net.checkpoint.check_checkpoint): a truncated
file, random bytes, weights that do not fit model_config, bad sizes and a missing or broken .onnx are each one
InputError naming the file and the problem; the learned controller gives the same messages."""

from __future__ import annotations

import os

import pytest
import torch
from eval_fixtures import make_fixture_project

from expoctl.controllers.registry import make_controller
from expoctl.errors import InputError
from expoctl.net.checkpoint import check_checkpoint, export_onnx, load_checkpoint


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """The fixture project's tiny untrained checkpoint (models/controller.pt) with its .onnx beside it."""
    root = tmp_path_factory.mktemp("ckpt")
    make_fixture_project(root)
    path = root / "models/controller.pt"
    model, _ = load_checkpoint(path)
    export_onnx(model, path.with_suffix(".onnx"))
    return path


def _copy(src, dst, data: bytes | None = None, onnx: bool = True):
    dst.write_bytes(src.read_bytes() if data is None else data)
    if onnx:
        dst.with_suffix(".onnx").write_bytes(src.with_suffix(".onnx").read_bytes())
    return dst


def test_a_good_checkpoint_passes_with_its_onnx(good):
    ckpt = check_checkpoint(good, onnx=True)
    assert ckpt["input_hw"] == [32, 32] and ckpt["store_hw"] == [48, 64]


def test_truncated_checkpoint_names_the_file(good, tmp_path):
    data = good.read_bytes()
    bad = _copy(good, tmp_path / "controller_final.pt", data[: len(data) // 2])
    with pytest.raises(InputError) as e:
        check_checkpoint(bad)
    assert str(e.value) == (f"{bad}: truncated or not a PyTorch file ({len(data) // 2} bytes; the zip archive "
                            "torch.save writes has no end record: [Errno 22] Invalid argument)")


def test_random_bytes_name_the_file(good, tmp_path):
    bad = _copy(good, tmp_path / "noise.pt", os.urandom(3000))
    with pytest.raises(InputError) as e:
        check_checkpoint(bad)
    assert str(e.value) == (f"{bad}: truncated or not a PyTorch file (3000 bytes, not starting with the zip header "
                            "torch.save writes)")


def test_empty_and_missing_files(good, tmp_path):
    empty = _copy(good, tmp_path / "empty.pt", b"")
    with pytest.raises(InputError, match=f"^{empty}: empty file, not a PyTorch checkpoint$"):
        check_checkpoint(empty)
    with pytest.raises(InputError, match=f"^{tmp_path / 'missing.pt'}: model checkpoint not found$"):
        check_checkpoint(tmp_path / "missing.pt")


def test_state_dict_that_does_not_match_model_config(good, tmp_path):
    ckpt = torch.load(good, weights_only=True)
    ckpt["model_config"]["conv_widths"] = [6, 4, 8, 8]  # the weights are of a 4-wide first conv
    bad = tmp_path / "wide.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputError) as e:
        check_checkpoint(bad)
    assert str(e.value) == (
        f"{bad}: state_dict does not match model_config: features.0.weight has shape [4, 15, 3, 3], expected "
        "[6, 15, 3, 3]; features.0.bias has shape [4], expected [6]; features.2.weight has shape [4], expected [6]; "
        "features.2.bias has shape [4], expected [6]; features.2.running_mean has shape [4], expected [6]; "
        "features.2.running_var has shape [4], expected [6]; features.5.weight has shape [4, 4, 3, 3], expected "
        "[4, 6, 3, 3]")


def test_missing_and_unexpected_keys(good, tmp_path):
    ckpt = torch.load(good, weights_only=True)
    ckpt["state_dict"]["extra.weight"] = ckpt["state_dict"].pop("head.1.weight")
    bad = tmp_path / "keys.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputError) as e:
        check_checkpoint(bad)
    assert str(e.value) == (f"{bad}: state_dict does not match model_config: head.1.weight missing; "
                            "unexpected key extra.weight")


@pytest.mark.parametrize("key,value,problem", [
    ("input_hw", [24, 24], "input_hw [24, 24] differs from model_config.input_size [32, 32] (the network only takes "
                           "the latter)"),
    ("store_hw", [48], "store_hw must be [height, width], two integers in 1–8192, got [48]"),
    ("store_hw", [0, 64], "store_hw must be [height, width], two integers in 1–8192, got [0, 64]"),
    ("format", "other", "not an expoctl controller checkpoint (format expoctl-controller-v1 expected, found 'other')"),
])
def test_bad_metadata(good, tmp_path, key, value, problem):
    ckpt = torch.load(good, weights_only=True)
    ckpt[key] = value
    bad = tmp_path / "meta.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputError) as e:
        check_checkpoint(bad)
    assert str(e.value) == f"{bad}: {problem}"


def test_bad_model_config_names_the_file_and_key(good, tmp_path):
    ckpt = torch.load(good, weights_only=True)
    ckpt["model_config"]["dropout"] = "high"
    bad = tmp_path / "cfg.pt"
    torch.save(ckpt, bad)
    with pytest.raises(InputError, match=f"^{bad}: bad model_config: config key 'model_config.dropout': must be a "
                                         "finite number, got 'high'$"):
        check_checkpoint(bad)


def test_missing_truncated_and_mismatched_onnx(good, tmp_path):
    bad = _copy(good, tmp_path / "noonnx.pt", onnx=False)
    check_checkpoint(bad)  # the .onnx is only checked where it is needed
    with pytest.raises(InputError) as e:
        check_checkpoint(bad, onnx=True)
    assert str(e.value) == (f"{tmp_path / 'noonnx.onnx'}: ONNX export missing (it is written beside the checkpoint by "
                            "the train stage)")
    cut = _copy(good, tmp_path / "cut.pt")
    onnx = good.with_suffix(".onnx").read_bytes()
    cut.with_suffix(".onnx").write_bytes(onnx[: len(onnx) // 2])
    with pytest.raises(InputError, match=f"^{tmp_path / 'cut.onnx'}: not loadable by onnxruntime: truncated or not an "
                                         f"ONNX model \\({len(onnx) // 2} bytes; "):
        check_checkpoint(cut, onnx=True)
    # an .onnx of another input size than the checkpoint's
    other = make_fixture_project(tmp_path / "p2")  # noqa: F841 — writes p2/models/controller.pt
    ckpt = torch.load(tmp_path / "p2/models/controller.pt", weights_only=True)
    for k in ("model_config",):
        ckpt[k]["input_size"] = [24, 24]
    ckpt["input_hw"] = [24, 24]
    from expoctl.net.model import ExposureNet, ModelConfig

    model = ExposureNet(ModelConfig.from_dict(ckpt["model_config"])).eval()
    export_onnx(model, tmp_path / "small.onnx")
    mixed = _copy(good, tmp_path / "mixed.pt", onnx=False)
    mixed.with_suffix(".onnx").write_bytes((tmp_path / "small.onnx").read_bytes())
    with pytest.raises(InputError) as e:
        check_checkpoint(mixed, onnx=True)
    assert str(e.value) == (f"{tmp_path / 'mixed.onnx'}: ONNX input has shape ['batch', 15, 24, 24], expected "
                            "[batch, 15, 32, 32] (the checkpoint's input_hw)")


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_the_learned_controller_gives_the_same_messages(good, tmp_path, backend):
    data = good.read_bytes()
    bad = _copy(good, tmp_path / "controller_final.pt", data[: len(data) // 2])
    with pytest.raises(InputError) as e:
        make_controller("learned", {"checkpoint": str(bad), "backend": backend})
    with pytest.raises(InputError) as direct:
        check_checkpoint(bad)
    assert str(e.value) == str(direct.value) and str(e.value).startswith(f"{bad}: truncated or not a PyTorch file")
    if backend == "onnx":
        ok = _copy(good, tmp_path / "ok.pt", onnx=False)
        with pytest.raises(InputError, match=f"^{tmp_path / 'ok.onnx'}: ONNX export missing"):
            make_controller("learned", {"checkpoint": str(ok), "backend": "onnx"})
