"""`softhand bench --plot FILE.png`: where each case's step goes, and how its steps vary.

Left: one bar per case, its mean step split into the solver's stages (each stage's share of the
step times the mean step, so the bar's length is the mean), with the case's median step (a line)
and p99 step (a diamond). Right: every step of every case in run order, on a log scale: a scene
that moves and then holds shows as two levels (its p99 from the first, its median from the
second), a factorization in slices as a regular comb.
"""
import matplotlib

matplotlib.use("Agg")  # no display needed (CI, ssh)
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402

# the stages as --profile names them (solver.STAGE_FIELDS, then `other`); a stage added there
# later gets a grey until it is given a colour here
STAGE_COLORS = {"collision": "#8c564b", "self_collision": "#e377c2", "assembly": "#1f77b4",
                "factor": "#d62728", "pcg": "#2ca02c", "advance": "#9467bd", "other": "#7f7f7f"}


def case_label(row):
    """A case's name in the picture: scenario, mesh, hands, threads, and any --set or non-default
    preconditioner."""
    label = f"{row['scenario']} {row['mesh']}"
    if row["hands"] > 1:
        label += f", {row['hands']} hands, {row['threads']} thr"
    if row["preconditioner"] != "factor":
        label += f", {row['preconditioner']}"
    for key, value in row.get("settings", {}).items():
        label += f", {key}={value}"
    return label


def plot_profile(rows, path):
    """Write the picture of `rows` (softhand bench rows with `stages` and `step_ms`) to path;
    returns the case labels in drawing order (top to bottom)."""
    labels = [case_label(r) for r in rows]
    fig, (bars, series) = plt.subplots(1, 2, figsize=(15, 2.6 + 0.55 * len(rows)),
                                       gridspec_kw={"width_ratios": [1.1, 1.0]})
    y = np.arange(len(rows))[::-1]  # the first case on top
    for yi, row in zip(y, rows):
        left = 0.0
        for name, stage in row["stages"].items():
            width = stage["share"] * row["mean_ms"]
            bars.barh(yi, width, left=left, color=STAGE_COLORS.get(name, "#bbbbbb"), height=0.6,
                      label=name if yi == y[0] else None)
            left += width
        bars.plot([row["median_ms"]] * 2, [yi - 0.38, yi + 0.38], color="black", lw=1.5,
                  label="median step" if yi == y[0] else None)
        bars.plot(row["p99_ms"], yi, marker="D", color="black", ms=5, ls="none",
                  label="p99 step" if yi == y[0] else None)
        bars.text(row["p99_ms"], yi, f"  {row['median_ms']:.2f} / {row['p99_ms']:.2f} ms",
                  va="center", fontsize=8)
    bars.set_yticks(y, labels, fontsize=8)
    bars.set_xlabel("ms per step (bar: the mean, by stage)")
    bars.set_xlim(0, 1.35 * max(r["p99_ms"] for r in rows))
    bars.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=5)
    bars.set_title("where the step goes")
    for row, label in zip(rows, labels):
        series.plot(np.arange(len(row["step_ms"])), row["step_ms"], lw=0.8, label=label)
    series.set_yscale("log")
    # ticks at 1, 2, 5 per decade, written 0.5 rather than 5e-1
    series.yaxis.set_major_locator(matplotlib.ticker.LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    series.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    series.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    series.set_xlabel("step")
    series.set_ylabel("ms")
    series.legend(fontsize=7, loc="upper right")
    series.set_title("every step, in run order")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return labels
