"""PNG plots of an identification (matplotlib, Agg backend): heading error before/after, the
effective track T_E against curvature before/after, and the loss curve."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def pyplot():
    """matplotlib.pyplot on the Agg backend (files only, no display), imported on first use."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path, dpi: int = 110) -> Path:
    """Lay out ``fig``, write it as a PNG to ``path`` (creating the folder) and close it."""
    path = Path(path)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def _name(drive) -> str:
    p = str(drive.metadata.get("path", "<columns>")) if getattr(drive, "metadata", None) else "<columns>"
    return Path(p).name if "/" in p else p


def heading_error_plot(path: Path, ev_before, ev_after, drives, roles, mode: str) -> Path:
    plt = pyplot()
    field = "wheel_heading" if mode == "odometer" else "heading"
    label = "odometer-only heading" if mode == "odometer" else f"{mode} heading"
    n = len(drives)
    fig, axes = plt.subplots(n, 1, figsize=(10, 2.4 * n + 0.6), squeeze=False, sharex=False)
    for b in range(n):
        ax = axes[b, 0]
        w = ev_before["weight"][b] > 0
        t = ev_before["time_s"][b]
        t = t - t[0]
        for ev, tag, color in ((ev_before, "before", "tab:red"), (ev_after, "after", "tab:blue")):
            e = np.degrees(np.angle(np.exp(1j * (ev[field][b] - ev["ref"][b]))))
            rms = np.sqrt(np.mean(e[w] ** 2)) if np.any(w) else float("nan")
            ax.plot(t[w], e[w], color=color, lw=0.8, label=f"{tag} (RMSE {rms:.2f}°)")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel("error, deg")
        ax.set_title(f"{roles[b]}: {_name(drives[b])}", fontsize=9)
        ax.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("time, s")
    fig.suptitle(f"{label} error against the reference, before and after identification", fontsize=10)
    return save_figure(fig, path)


def _empirical_track(ev, drives, params, n_train: int, bins, half_window_m: float = 1.5):
    """Track implied by the data per curvature bin: sum s dD / sum s dpsi_ref (1 + a V²).

    Samples are binned by the curvature of the *reference* heading over +-half_window_m of travel
    (times the fitted T_E(c)(1 + aV²), to be in dD/AD units), not by the estimator's curvature: that one
    is computed from the same quantized pulses as dD, and selecting on it biases the ratio.  s is the
    sign of the reference heading change over the window, so noise averages out and reversing does
    not cancel driving forwards."""
    from jaxmodel.track import effective_track

    from .drive_log import counter_increments

    num, den, c_all = [], [], []
    t_f = float(params.T_F)
    for b in range(n_train):
        inp = drives[b].inputs
        n = len(np.asarray(inp.time_s))
        mod = float(params.counter_modulus)
        dl = counter_increments(inp.left_pulses, mod) * float(params.dpp_left)
        dr = counter_increments(inp.right_pulses, mod) * float(params.dpp_right)
        dD = dl - dr
        dist = np.cumsum(np.abs(0.5 * (dl + dr)))
        ref = ev["ref"][b][:n]
        dpsi = np.angle(np.exp(1j * np.diff(ref, prepend=ref[0])))
        lo = np.clip(np.searchsorted(dist, dist - half_window_m, side="left"), 0, n - 1)
        hi = np.clip(np.searchsorted(dist, dist + half_window_m, side="right") - 1, 0, n - 1)
        span = dist[hi] - dist[lo]
        turn = np.angle(np.exp(1j * (ref[hi] - ref[lo])))
        v = ev["speed"][b][:n]
        gain = 1.0 + ev["a"][b][:n] * v * v
        w = (ev["weight"][b][:n] > 0) & (np.roll(ev["weight"][b][:n], 1) > 0) & (span > half_window_m)
        w[0] = False
        kappa = np.where(span > 0, np.abs(turn) / np.where(span > 0, span, 1.0), 0.0) * gain
        c_ref = kappa * t_f
        if float(params.sensor_axle) >= 0.5:  # c = kappa T_E(c): a few fixed-point steps on the fitted curve
            for _ in range(3):
                c_ref = kappa * np.asarray(effective_track(c_ref, params.P, params.B, params.T_F, params.curvature_clip))
        else:
            c_ref = kappa * float(params.T_R)
        s = np.sign(turn)
        num.append((s * dD)[w])
        den.append((s * dpsi * gain)[w])
        c_all.append(c_ref[w])
    num, den, c = (np.concatenate(x) if x else np.zeros(0) for x in (num, den, c_all))
    centers, values = [], []
    for lo_c, hi_c in zip(bins[:-1], bins[1:]):
        sel = (c >= lo_c) & (c < hi_c)
        d = np.sum(den[sel])
        if lo_c >= 0.02 and sel.sum() > 100 and d > np.radians(180.0):
            centers.append(0.5 * (lo_c + hi_c))
            values.append(np.sum(num[sel]) / d)
    return np.array(centers), np.array(values), c


def track_plot(path: Path, start, fitted, ev_after, drives, n_train: int) -> Path:
    from jaxmodel.track import effective_track, max_curvature

    plt = pyplot()
    fig, (ax, axh) = plt.subplots(2, 1, figsize=(8, 6.5), gridspec_kw={"height_ratios": [3, 1]}, sharex=True)
    c_max = 0.98 * float(max_curvature(fitted.B, fitted.T_F))
    c = np.linspace(0.0, c_max, 300)
    for p, tag, color in ((start, "before (start file)", "tab:red"), (fitted, "after (fitted)", "tab:blue")):
        if float(p.sensor_axle) >= 0.5:
            te = np.asarray(effective_track(c, p.P, p.B, p.T_F, p.curvature_clip))
        else:
            te = np.full_like(c, float(p.T_R))
        ax.plot(c, te, color=color, label=tag)
    bins = np.linspace(0.0, c_max, 15)
    centers, values, c_data = _empirical_track(ev_after, drives, fitted, n_train, bins)
    if centers.size:
        ax.plot(centers, values, "ko", ms=4, label="implied by the training data (binned by reference curvature)")
    ax.set_ylabel("effective track T_E, m")
    ax.set_title("US 4,788,645 eq. (14): effective track against curvature dD/AD", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    if c_data.size:
        axh.hist(c_data, bins=60, range=(0.0, c_max), color="0.5")
        axh.set_yscale("log")
    axh.set_xlabel("|curvature| dD/AD (training data, from the reference heading)")
    axh.set_ylabel("samples")
    return save_figure(fig, path)


def loss_plot(path: Path, stage_reports) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for st in stage_reports:
        h = np.asarray(st["loss_history"], dtype=np.float64)
        if h.size:
            line, = ax.plot(np.arange(h.size), h - h[-1] + 1e-9, marker=".",
                            label=f"{st['name']}: {','.join(st['keys'])}")
            h2 = np.asarray(st.get("loss_history_refit", []), dtype=np.float64)
            if h2.size:
                ax.plot(np.arange(h.size - 1, h.size - 1 + h2.size), h2 - h2[-1] + 1e-9, ls="--", marker=".",
                        color=line.get_color(),
                        label=f"{st['name']}: refit with {','.join(st['refit_with_fixed'])} kept at start")
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("MAP objective - its final value (nats)")
    ax.set_title("identification loss curve", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def write_all(out_dir: Path, ev_before, ev_after, drives, roles, start, fitted, stage_reports, mode, n_train):
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [
        heading_error_plot(out_dir / "heading_error.png", ev_before, ev_after, drives, roles, mode),
        track_plot(out_dir / "effective_track.png", start, fitted, ev_after, drives, n_train),
        loss_plot(out_dir / "loss.png", stage_reports),
    ]
