"""Does a network raise gain once exposure is spent? Open-loop predictions against labels, tunnel vs open road (not a
test; issue 25, the libviso2-style miss).

In closed loop the calibrated default network's libviso2-style minima sit inside tunnels, on dark frames (mean grey
20–45) where it runs at the 30 ms exposure cap with about 1 dB of gain while AG+AE and the oracle run 15–30 dB. This
asks whether that is in the labels or in the network: on the recorded samples of a split (whose inputs came from the
rig's controllers, not from the network), it compares, per region, the frame-t input setting, the label and the
network's raw prediction. A sample is "tunnel" when frame t's exposure is within `--cap-margin-ev` of the cap
(the only way left to add light is gain); "open road" otherwise.

    .venv/bin/python benchmarks/archive/tunnel_gain.py --model models/controller_final.pt --samples data/iter2/samples.parquet \
        --frames data/iter2/frames.parquet --images-dir data/iter2/images [--split validation] [--out FILE.json]

Prints one row per region: samples, median input/label/predicted gain (dB), median label and predicted step in
exposure product (EV, relative to the frame-t input), median |prediction − label| (EV), and the slope of the
predicted gain step on the label's gain step (1 = follows the labels, 0 = ignores them).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.camera.ranges import EXPOSURE_US_MAX, exposure_value_ev, norm_to_exposure, norm_to_gain  # noqa: E402
from expoctl.net.dataset import load_sample_sets_from_files, predict  # noqa: E402
from expoctl.errors import InputError  # noqa: E402
from expoctl.net.checkpoint import load_checkpoint  # noqa: E402


def region_rows(input_gain, input_exp, label_gain, label_exp, pred_gain, pred_exp, tunnel) -> list[dict]:
    """Per-region medians and the gain-step slope (arrays in dB and µs; `tunnel` boolean)."""
    ev = exposure_value_ev
    rows = []
    for name, mask in (("open road", ~tunnel), ("tunnel", tunnel), ("all", np.ones_like(tunnel))):
        if not mask.any():
            continue
        gi, ei, gl, el, gp, ep = (a[mask] for a in (input_gain, input_exp, label_gain, label_exp, pred_gain, pred_exp))
        d_label, d_pred = gl - gi, gp - gi
        slope = float(np.polyfit(d_label, d_pred, 1)[0]) if np.ptp(d_label) > 0 and len(gi) >= 2 else float("nan")
        rows.append({
            "region": name, "n": int(mask.sum()),
            "input_gain_db": float(np.median(gi)), "label_gain_db": float(np.median(gl)),
            "pred_gain_db": float(np.median(gp)),
            "label_step_ev": float(np.median(ev(gl, el) - ev(gi, ei))),
            "pred_step_ev": float(np.median(ev(gp, ep) - ev(gi, ei))),
            "abs_error_ev": float(np.median(np.abs(ev(gp, ep) - ev(gl, el)))),
            "gain_step_slope": slope,
        })
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--samples", required=True)
    ap.add_argument("--frames", required=True)
    ap.add_argument("--images-dir", required=True)
    ap.add_argument("--split", default="validation")
    ap.add_argument("--cap-margin-ev", type=float, default=0.1,
                    help="frame t within this many EV of the exposure cap counts as tunnel (default 0.1)")
    ap.add_argument("--out", help="write the rows as JSON here")
    args = ap.parse_args(argv)
    try:
        model, ckpt = load_checkpoint(args.model)
        cfg = ckpt["model_config"]
        scale = cfg.get("exposure_scale", "linear")
        sets = load_sample_sets_from_files(args.samples, args.frames, args.images_dir, cfg["input_size"],
                                           splits=(args.split,), exposure_scale=scale)
    except InputError as exc:
        print(f"tunnel_gain: {exc}", file=sys.stderr)
        return 2
    data = sets[args.split]
    pred = predict(model, data)
    input_gain = norm_to_gain(data.gain_norm[:, 0].numpy())
    input_exp = norm_to_exposure(data.exposure_norm[:, 0].numpy(), scale)
    label_gain = norm_to_gain(data.targets[:, 0].numpy())
    label_exp = norm_to_exposure(data.targets[:, 1].numpy(), scale)
    pred_gain, pred_exp = norm_to_gain(pred[:, 0]), norm_to_exposure(pred[:, 1], scale)
    tunnel = np.log2(EXPOSURE_US_MAX / input_exp) <= args.cap_margin_ev
    rows = region_rows(input_gain, input_exp, label_gain, label_exp, pred_gain, pred_exp, tunnel)
    table = pd.DataFrame(rows).set_index("region")
    print(f"{args.model} on {args.samples} ({args.split}, {len(data)} samples)")
    print(table.round(2).to_string())
    if args.out:
        out = Path(args.out)
        tmp = out.with_suffix(out.suffix + ".tmp")
        tmp.write_text(json.dumps({"model": args.model, "samples": args.samples, "split": args.split,
                                   "cap_margin_ev": args.cap_margin_ev, "rows": rows}, indent=1) + "\n")
        tmp.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
