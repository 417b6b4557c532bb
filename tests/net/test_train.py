"""Training: loss, physical errors, baseline, determinism, early stopping, checkpoint and ONNX agreement."""

from __future__ import annotations

import dataclasses

import numpy as np
import onnxruntime as ort
import pytest
import torch

from expoctl.net.dataset import load_sample_sets_from_files
from expoctl.errors import ConfigError, InputError
from expoctl.net.model import ExposureNet, ModelConfig
from tests.support.synthetic_data import make_synthetic_dataset
from expoctl.net.train import (OnDevice, TrainConfig, complement_partners, error_sums, fit, hold_prediction,
                               metrics_from_sums, predict, resolve_device, weighted_l1)
from expoctl.net.checkpoint import checkpoint_dict, export_onnx, load_checkpoint

TINY = ModelConfig(input_size=(32, 32), conv_kernels=(3, 3, 3), pool=2, conv_widths=(8, 16, 16, 32),
                   fc_widths=(16, 8, 8), dropout=0.1)


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    p = make_synthetic_dataset(tmp_path_factory.mktemp("syn"), n_sequences=5, n_frames=14, hw=(32, 32), seed=0)
    return load_sample_sets_from_files(p["samples"], p["frames"], p["images_dir"], 32)


def test_weighted_l1():
    pred = torch.tensor([[0.5, 0.2], [0.1, 0.9]])
    target = torch.tensor([[0.1, 0.2], [0.3, 0.5]])
    # gain |0.4|, |0.2| → 0.3; exposure 0, 0.4 → 0.2
    assert float(weighted_l1(pred, target, 0.25)) == pytest.approx(0.25 * 0.3 + 0.75 * 0.2)


def test_errors_in_db_and_ev_after_clamping():
    # gain 0.5→15 dB vs 0.6→18 dB: 3 dB; exposure norm 1.2 clamps to 30000 µs vs 15000 µs... one EV
    e_half = (15000 - 75) / (30000 - 75)
    m = metrics_from_sums(error_sums(np.array([[0.5, 1.2]]), np.array([[0.6, e_half]]), 0.5), 0.5)
    assert m["gain_mae_db"] == pytest.approx(3.0)
    assert m["exposure_mae_ev"] == pytest.approx(1.0)


def test_config_errors_name_keys():
    with pytest.raises(ConfigError, match="train.epsilon"):
        TrainConfig.from_dict({"epsilon": 1.5})
    with pytest.raises(ConfigError, match="train.learning_rate"):
        TrainConfig.from_dict({"learning_rate": 1e-3})


def test_value_that_does_not_convert_names_its_own_key_and_every_problem_is_reported():
    with pytest.raises(ConfigError) as exc:
        TrainConfig.from_dict({"lr": "abc", "epochs": [1], "exposure_shift_ev": 3, "max_train_samples": "x",
                               "epsilon": 1.5, "learning_rate": 1e-3})
    known = sorted(f.name for f in dataclasses.fields(TrainConfig))
    assert exc.value.problems == [  # one reader (config_reader.read_config): types, then bounds, then unknown keys
        ("train.lr", "must be a finite number, got 'abc'"),
        ("train.epochs", "must be an integer, got [1]"),
        ("train.max_train_samples", "must be an integer or null, got 'x'"),
        ("train.exposure_shift_ev", "must be a non-empty list of finite numbers, got 3"),
        ("train.epsilon", "must be in [0, 1], got 1.5"),
        ("train.learning_rate", f"unknown key (expected one of {known})"),
    ]
    with pytest.raises(ConfigError) as exc:  # no silent rounding: 2.7 epochs is not 2
        TrainConfig.from_dict({"epochs": 2.7, "exposure_shift_ev": [1.0, 2.0, 3.0]})
    assert exc.value.problems == [("train.epochs", "must be an integer, got 2.7"),
                                  ("train.exposure_shift_ev", "must be a list of 2 numbers, got [1.0, 2.0, 3.0]")]
    with pytest.raises(ConfigError) as exc:
        TrainConfig.from_dict({"lr": -1})
    assert exc.value.problems == [("train.lr", "must be > 0, got -1.0")]


def test_fit_learns_beats_baseline_and_is_deterministic(sets):
    cfg = TrainConfig(lr=3e-3, batch_size=32, epochs=8, patience=8, num_threads=1)
    seen = []
    r1 = fit(TINY, cfg, sets["train"], sets["validation"], seed=3, on_epoch=lambda e, m: seen.append((e, m)))
    assert [e for e, _ in seen] == list(range(r1.epochs_run))
    assert r1.history[-1]["train_loss"] < r1.history[0]["train_loss"]
    m = r1.metrics
    assert m["beats_baseline"] and m["val_loss"] < m["baseline_val_loss"]
    assert m["val_loss"] == pytest.approx(min(h["val_loss"] for h in r1.history))  # best checkpoint restored
    assert m["improvement_exposure_ev"] == pytest.approx(m["baseline_val_exposure_mae_ev"] - m["val_exposure_mae_ev"])
    r2 = fit(TINY, cfg, sets["train"], sets["validation"], seed=3)
    for (k, a), b in zip(r1.model.state_dict().items(), r2.model.state_dict().values()):
        assert torch.equal(a, b), k


def test_early_stopping(sets):
    # lr so small nothing improves by min_delta after the first epoch → stops after 1 + patience epochs
    cfg = TrainConfig(lr=1e-9, batch_size=32, epochs=50, patience=2, min_delta=0.5, num_threads=1)
    r = fit(TINY, cfg, sets["train"], sets["validation"], seed=0)
    assert r.epochs_run == 3 and r.best_epoch == 0


def test_train_subset_fixed_or_per_epoch(sets):
    n = len(sets["train"])
    base = dict(lr=1e-3, batch_size=8, epochs=4, patience=10, num_threads=1, max_train_samples=n // 4)
    fixed = fit(TINY, TrainConfig(**base), sets["train"], sets["validation"], seed=1).metrics
    assert fixed["n_train_samples"] == fixed["n_distinct_train_samples"] == n // 4
    fresh = fit(TINY, TrainConfig(**base, train_subset="per_epoch"), sets["train"], sets["validation"], seed=1).metrics
    # 4 independent draws of a quarter each: expected distinct share 1 − 0.75⁴ ≈ 68 % (a fixed subset: 25 %)
    assert fresh["n_train_samples"] == n // 4
    assert fresh["n_distinct_train_samples"] > 0.5 * n
    with pytest.raises(ConfigError, match="train.train_subset"):
        TrainConfig.from_dict({"train_subset": "each"})


def test_complement_partner_takes_every_frame_from_the_other_camera():
    cams = np.array([(a, b, c) for a in (1, 2) for b in (1, 2) for c in (1, 2)])
    steps = [5, 9, 2]
    time_step = np.repeat(steps, 8)
    cameras = np.tile(cams, (3, 1))
    order = np.random.default_rng(0).permutation(len(time_step))  # order of the table must not matter
    time_step, cameras = time_step[order], cameras[order]
    # a time step with only one sample (a filtered table): its own partner
    time_step, cameras = np.append(time_step, 7), np.vstack([cameras, [1, 2, 1]])
    partner = complement_partners(time_step, cameras)
    assert np.array_equal(time_step[partner], time_step)
    assert np.array_equal(cameras[partner[:-1]], 3 - cameras[:-1])
    assert partner[-1] == len(time_step) - 1
    assert np.array_equal(partner[partner], np.arange(len(time_step)))  # an involution: pairs, both ways


def test_consistency_weight_is_validated():
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="train.consistency_weight"):
            TrainConfig.from_dict({"consistency_weight": bad})
    with pytest.raises(ConfigError, match="train"):
        TrainConfig.from_dict({"consistency_weight": "strong"})


def _camera_spread(model, data) -> float:
    """Mean over time steps of the range of the (gain, exposure) outputs across its camera combinations."""
    pred = predict(model, data)
    return float(np.mean([np.ptp(pred[data.time_step == s], axis=0).sum() for s in np.unique(data.time_step)]))


def test_consistency_term_makes_outputs_agree_across_cameras(sets):
    base = dict(lr=3e-3, batch_size=32, epochs=6, patience=6, num_threads=1)
    plain = fit(TINY, TrainConfig(**base), sets["train"], sets["validation"], seed=2)
    tied = fit(TINY, TrainConfig(**base, consistency_weight=5.0), sets["train"], sets["validation"], seed=2)
    again = fit(TINY, TrainConfig(**base, consistency_weight=5.0), sets["train"], sets["validation"], seed=2)
    for (k, a), b in zip(tied.model.state_dict().items(), again.model.state_dict().values()):
        assert torch.equal(a, b), k  # partners are drawn reproducibly
    # the samples of one time step share one label: the tied network's outputs spread less across its cameras
    spread_plain = _camera_spread(plain.model, sets["validation"])
    spread_tied = _camera_spread(tied.model, sets["validation"])
    assert spread_tied < 0.5 * spread_plain, (spread_tied, spread_plain)
    assert tied.metrics["beats_baseline"]
    # ... and the open-loop follow that fit reports (expoctl.net.follow) is closer to 0, "reads the scene" (the
    # plain network over-corrects on these synthetic data: its follow is negative)
    assert abs(tied.metrics["val_follow"]) < 0.5 * abs(plain.metrics["val_follow"])


def test_input_size_mismatch_is_a_config_error(sets):
    cfg = ModelConfig(input_size=(40, 40), conv_kernels=(3, 3, 3), pool=2)
    with pytest.raises(ConfigError, match="model.input_size"):
        fit(cfg, TrainConfig(epochs=1), sets["train"], sets["validation"], seed=0)


def test_residual_log_model_learns_and_exports(sets, tmp_path):
    cfg_m = ModelConfig(**{**TINY.__dict__, "output": "residual"})
    r = fit(cfg_m, TrainConfig(lr=3e-3, batch_size=32, epochs=4, patience=4, num_threads=1), sets["train"],
            sets["validation"], seed=1)
    assert r.history[0]["val_loss"] > 0 and r.metrics["val_loss"] <= r.history[0]["val_loss"]
    path = tmp_path / "res.onnx"
    export_onnx(r.model, path)
    x, _ = sets["validation"].batch(np.arange(6))
    with torch.no_grad():
        ref = r.model(x).numpy()
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"input": x.numpy()})[0]
    np.testing.assert_allclose(got, ref, atol=1e-4)


def test_exposure_scale_mismatch_is_a_config_error(sets):
    with pytest.raises(ConfigError, match="model.exposure_scale"):
        fit(ModelConfig(**{**TINY.__dict__, "exposure_scale": "log"}), TrainConfig(epochs=1), sets["train"],
            sets["validation"], seed=0)


def test_errors_in_ev_under_log_scaling():
    # log scaling: 1/8.64 of the range is one stop, wherever it is
    step = 1 / np.log2(30000 / 75)
    m = metrics_from_sums(error_sums(np.array([[0.1, 0.2 + step]]), np.array([[0.1, 0.2]]), 0.5, "log"), 0.5)
    assert m["exposure_mae_ev"] == pytest.approx(1.0) and m["gain_mae_db"] == 0.0


def test_hold_baseline_is_frame_t_settings(sets):
    val = sets["validation"]
    rows = np.arange(len(val))
    hold = hold_prediction(val, rows)
    np.testing.assert_array_equal(hold[:, 0], val.gain_norm[:, 0].numpy())
    np.testing.assert_array_equal(hold[:, 1], val.exposure_norm[:, 0].numpy())
    r = fit(TINY, TrainConfig(epochs=1, batch_size=32, num_threads=1), sets["train"], val, seed=0)
    expect = metrics_from_sums(error_sums(hold, val.targets.numpy(), 0.5), 0.5)
    assert r.metrics["hold_val_exposure_mae_ev"] == pytest.approx(expect["exposure_mae_ev"])
    assert r.metrics["hold_val_gain_mae_db"] == pytest.approx(expect["gain_mae_db"])


def test_checkpoint_roundtrip_and_onnx_matches_torch(sets, tmp_path):
    cfg = TrainConfig(lr=3e-3, batch_size=32, epochs=2, num_threads=1)
    r = fit(TINY, cfg, sets["train"], sets["validation"], seed=0)
    torch.save(checkpoint_dict(r, TINY, cfg, sets["train"].store_hw, seed=0), tmp_path / "controller.pt")
    model, ckpt = load_checkpoint(tmp_path / "controller.pt")
    assert ckpt["input_hw"] == [32, 32] and ckpt["store_hw"] == [32, 32]
    ref = predict(r.model, sets["validation"])
    assert np.array_equal(predict(model, sets["validation"]), ref)

    export_onnx(model, tmp_path / "controller.onnx")
    sess = ort.InferenceSession(str(tmp_path / "controller.onnx"), providers=["CPUExecutionProvider"])
    x, _ = sets["validation"].batch(np.arange(len(sets["validation"])))
    out = sess.run(None, {"input": x.numpy()})[0]
    assert out.shape == ref.shape
    assert np.abs(out - ref).max() < 1e-4
    single = sess.run(None, {"input": x[:1].numpy()})[0]  # batch size 1 (deployment) works too
    assert np.abs(single - ref[:1]).max() < 1e-4


def test_bad_checkpoint_is_input_error(tmp_path):
    (tmp_path / "x.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="x.pt"):
        load_checkpoint(tmp_path / "x.pt")
    with pytest.raises(InputError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt")


@pytest.mark.slow
def test_dynamo_exporter_matches_torch(sets, tmp_path):
    pytest.importorskip("onnxscript")
    r = fit(TINY, TrainConfig(batch_size=32, epochs=1, num_threads=1), sets["train"], sets["validation"], seed=0)
    export_onnx(r.model, tmp_path / "d.onnx", exporter="dynamo")
    sess = ort.InferenceSession(str(tmp_path / "d.onnx"), providers=["CPUExecutionProvider"])
    x, _ = sets["validation"].batch(np.arange(len(sets["validation"])))
    assert np.abs(sess.run(None, {"input": x.numpy()})[0] - predict(r.model, sets["validation"])).max() < 1e-4


# ---------------------------------------------------------------------------------------------------- train.device

def test_device_is_read_with_its_key_named():
    assert TrainConfig.from_dict({}).device == "auto"
    for v in ("auto", "cpu", "cuda"):
        assert TrainConfig.from_dict({"device": v}).device == v  # reading never needs the device itself
    with pytest.raises(ConfigError) as exc:
        TrainConfig.from_dict({"device": "gpu", "lr": -1})
    assert exc.value.problems == [("train.device", "must be one of auto, cpu, cuda, got 'gpu'"),
                                  ("train.lr", "must be > 0, got -1.0")]
    for bad in (["cuda"], 0, None):
        with pytest.raises(ConfigError, match="train.device"):
            TrainConfig.from_dict({"device": bad})
    with pytest.raises(ConfigError, match="train.device"):
        TrainConfig(device="tpu").validate()


def test_auto_resolves_to_cpu_here_and_cuda_without_cuda_is_named(monkeypatch):
    if not torch.cuda.is_available():  # this machine (no GPU): auto is the CPU
        assert resolve_device("auto") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert resolve_device("auto") == resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ConfigError, match="train.device") as exc:
        resolve_device("cuda")
    assert "torch.cuda.is_available() is False" in str(exc.value)
    with pytest.raises(ConfigError, match="train.device"):
        resolve_device("gpu")


def test_cuda_resolution_picks_the_local_rank(monkeypatch):
    """The resolution logic only (no CUDA here): one GPU per torchrun process, cuda:<LOCAL_RANK>."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 0)
    assert resolve_device("cuda", local_rank=1) == torch.device("cuda", 1)
    assert resolve_device("auto", local_rank=0) == torch.device("cuda", 0)
    assert resolve_device("auto") == torch.device("cuda", 0)  # not under torchrun: the current device
    assert resolve_device("cpu", local_rank=1) == torch.device("cpu")
    with pytest.raises(ConfigError, match="train.device"):
        resolve_device("cuda", local_rank=2)  # more processes than GPUs on the node


def test_cuda_without_cuda_stops_fit_before_any_work(sets, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ConfigError, match="train.device"):
        fit(TINY, TrainConfig(epochs=1, device="cuda"), sets["train"], sets["validation"], seed=0)


def test_cpu_run_is_identical_to_the_default_and_returns_a_cpu_model_in_eval_mode(sets):
    base = dict(lr=3e-3, batch_size=32, epochs=2, patience=4, num_threads=1, clipped_frame_weight=1.0)
    auto = fit(TINY, TrainConfig(**base), sets["train"], sets["validation"], seed=5)
    cpu = fit(TINY, TrainConfig(**base, device="cpu"), sets["train"], sets["validation"], seed=5)
    given = fit(TINY, TrainConfig(**base), sets["train"], sets["validation"], seed=5, device=torch.device("cpu"))
    for other in (cpu, given):
        for (k, a), b in zip(auto.model.state_dict().items(), other.model.state_dict().values()):
            assert torch.equal(a, b), k
        assert [h["val_loss"] for h in other.history] == [h["val_loss"] for h in auto.history]
        assert other.metrics["val_follow"] == auto.metrics["val_follow"]
    assert not auto.model.training
    assert {v.device.type for v in auto.model.state_dict().values()} == {"cpu"}


class _Stop(Exception):
    pass


def test_fit_trains_model_and_batches_on_the_device(sets, monkeypatch):
    """The `meta` device stands in for a GPU (shapes only, no values): the model's parameters, each batch's inputs
    (through the network's forward) and targets reach the loss on the device. Stopped at the first loss, before
    anything would need values."""
    import expoctl.net.train as train_mod

    seen = {}

    def spy(pred, target, epsilon):
        seen.update(pred=pred.device, target=target.device)
        raise _Stop

    monkeypatch.setattr(train_mod, "weighted_l1", spy)
    to_calls = []
    real_to = train_mod.ExposureNet.to

    def model_to(self, *a, **k):
        to_calls.append(a)
        return real_to(self, *a, **k)

    monkeypatch.setattr(train_mod.ExposureNet, "to", model_to)
    with pytest.raises(_Stop):
        fit(TINY, TrainConfig(epochs=1, batch_size=32, num_threads=1), sets["train"], sets["validation"], seed=0,
            device="meta")
    assert seen == {"pred": torch.device("meta"), "target": torch.device("meta")}
    assert to_calls == [(torch.device("meta"),)]


def test_on_device_wrapper_shares_the_models_mode_and_is_transparent_on_cpu(sets):
    model = ExposureNet(TINY)
    wrapped = OnDevice(model, torch.device("cpu"))
    wrapped.eval()
    assert not model.training and not wrapped.training
    model.train()  # the model's own mode is what helpers that save and restore `.training` see
    assert wrapped.training
    model.eval()
    x, _ = sets["validation"].batch(np.arange(4))
    with torch.no_grad():
        assert torch.equal(wrapped(x), model(x))
    assert list(wrapped.parameters()) == list(model.parameters())
