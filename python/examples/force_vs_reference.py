"""Load a recording, compare the calibrated force with the reference force, and plot them.
Trains nothing: the forces are the recorded ones, or (with --calibration) the calibration
applied offline with the same code as the live calibrator, at the curvature a curvature model
predicts from the recording's first no-load second (or --curvature-m1).

    python force_vs_reference.py demo.taxrec                       # recorded forces
    python force_vs_reference.py run.csv.gz --calibration cal.toml --model curvature.taxcrv
    python force_vs_reference.py demo.taxrec --out force.png       # needs matplotlib
"""

import argparse

import numpy as np

import taxel


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording", help=".taxrec, .mcap, .csv or .csv.gz")
    ap.add_argument("--calibration", help="apply this calibration instead of the recorded forces")
    ap.add_argument("--model", help="curvature model (.taxcrv) for --calibration")
    ap.add_argument("--curvature-m1", type=float, help="known curvature for --calibration")
    ap.add_argument("--out", help="write the plot here (PNG/SVG/PDF; needs matplotlib)")
    a = ap.parse_args()

    rec = taxel.read_recording(a.recording)
    print(rec)
    if "reference" not in rec:
        raise SystemExit(f"{a.recording} has no reference force")
    ref = rec["reference"]
    raw = rec["raw"]
    if a.calibration or "force" not in rec:
        if not a.calibration:
            raise SystemExit(f"{a.recording} has no force stream: give --calibration")
        cal = taxel.Calibration.load(a.calibration)
        t_s = raw["t_s"] if "t_s" in raw else raw["t_capture_ns"] * 1e-9
        counts = raw["counts"]
        # The first second is taken as the no-load baseline (as the estimator would find it).
        base = counts[t_s - t_s[0] < 1.0].mean(axis=0)
        curvature = a.curvature_m1
        if curvature is None and a.model:
            curvature = float(taxel.CurvatureModel.load(a.model).predict(base)["curvature_m1"][0])
            print(f"curvature from the model: {curvature:.1f} 1/m")
        out = cal.apply(counts, curvature_m1=curvature, baseline=base, t_s=t_s)
        t, force = t_s - t_s[0], out["total_force_n"]
        truth = ref["force_n"]
    else:
        f = rec["force"]
        by_seq = dict(zip(ref["seq"].tolist(), ref["force_n"].tolist()))
        keep = np.array([s in by_seq for s in f["seq"].tolist()])
        t = (f["t_capture_ns"][keep] - f["t_capture_ns"][keep][0]) * 1e-9
        force = f["total_force_n"][keep]
        truth = np.array([by_seq[s] for s in f["seq"][keep].tolist()])
    ok = np.isfinite(force) & np.isfinite(truth)
    loaded = ok & (truth > 0.5)
    err = np.abs(force[loaded] - truth[loaded])
    print(f"{ok.sum()} samples with a reference, {loaded.sum()} loaded (> 0.5 N): "
          f"mean absolute error {err.mean():.3f} N, mean relative error "
          f"{(err / truth[loaded]).mean() * 100:.1f} %" if loaded.any() else "no loaded samples")
    if a.out:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(9, 4))
        ax.plot(t, truth, label="reference", lw=1)
        ax.plot(t, force, label="taxel", lw=1)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("force (N)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(a.out)
        print(f"plot -> {a.out}")


if __name__ == "__main__":
    main()
