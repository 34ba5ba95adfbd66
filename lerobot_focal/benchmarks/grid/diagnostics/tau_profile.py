"""Where along the flow is a consistency model still wrong? The one-step prediction error at every flow time τ.

    lerobot-focal-bench tau-profile --out docs/benchmarks/grid_cpu_plateau \
        --methods focal,focal_online,wo_las,wo_fco_las

A consistency flow model acts through one map: from a point M_τ = (1 − τ)·M_0 + τ·M_1 of the straight path
between noise M_0 and an expert macro-trajectory M_1, it jumps to the data in one step,
f(M_τ, τ) = M_τ + (1 − τ)·v(M_τ, τ, o). Inference uses it once, at τ = ε (``anchor.eps``). The consistency loss
supervises it against the data only where the anchor r reaches the data end (r ≥ 1, or FlowPolicy's segment end)
and has to carry that down to τ = ε, one anchor hop at a time; FCO's λ·L_freq adds a weak direct term at every τ.
How far the data has come is measurable: the MetaWorld experts are deterministic, so the action chunk given the
observation is (nearly) one trajectory, and ‖f(M_τ, τ) − M_1‖² should be small at every τ once the signal has
arrived there. This measures it on each run's own demos (and on its held-out episodes), for the inference network
``lerobot-eval`` uses, at the flow times ``TAUS``:

* a profile that is low near τ = 1 and rises towards τ = ε says the data signal has not been carried all the way;
* a flat, low profile says the objective did its job, and what is left to explain is generalisation.

The error is in the policy's normalised action units (min-max to [−1, 1]), averaged over the valid (not padded)
steps of the proximal chunk (the executed one) and of the whole macro-trajectory; the reference is the variance of
M_1 around its mean trajectory (what predicting the average chunk would score). Fixed frames (evenly spaced
over the dataset) and fixed noise draws, so reruns and methods are compared on the same inputs. Writes
``tau_profile.json``, ``tau_profile.md`` and ``tau_profile.png`` beside the grid's report; runs already measured
are skipped. A low-dimensional run takes about half a minute (both datasets, one thread).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from ....console import doc_parser
from ....figures import save_png
from ..results import ResultsFile
from ..revisit import add_run_filters, measure_runs
from ..specs import checkpoint_of

TAUS = (0.01, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99)
FRAMES = 512  # evenly spaced frames per dataset
NOISE_DRAWS = 4  # noise trajectories per frame
NOISE_SEED = 0
WINDOWS = ("proximal", "macro")
#: Method pairs compared run by run (same task and seed) at the inference point, when both were measured.
PAIRS = (("wo_las", "wo_fco_las"), ("focal", "wo_las"), ("focal", "wo_fco_las"), ("focal", "focal_online"))


def one_step_errors(policy, batch: dict[str, torch.Tensor], taus: tuple[float, ...], noise: list[torch.Tensor]
                    ) -> dict[str, np.ndarray]:
    """Per window, (len(taus),): the squared error of f(M_τ, τ) against M_1 summed over the frames of a
    preprocessed batch (each frame averaged over its valid steps and the noise draws), so that batches of any size
    pool exactly."""
    net = policy._inference_net()
    cond = net.encode(policy._observations(batch, training=False))
    m1 = policy._check_actions(batch)
    valid = ~batch["action_is_pad"].bool() if "action_is_pad" in batch else torch.ones(m1.shape[:2], dtype=torch.bool)
    masks = {"proximal": valid.clone(), "macro": valid}
    masks["proximal"][:, policy.config.chunk_size:] = False
    counts = {w: m.sum(1).clamp(min=1) for w, m in masks.items()}
    sums = {w: np.zeros(len(taus)) for w in WINDOWS}
    for m0 in noise:
        for i, tau in enumerate(taus):
            m_t = (1.0 - tau) * m0 + tau * m1
            f = m_t + (1.0 - tau) * net.velocity(m_t, torch.full((m1.shape[0],), tau, dtype=m1.dtype), cond)
            err = (f - m1).pow(2).mean(-1)  # (B, L): mean over action dimensions
            for w in WINDOWS:
                sums[w][i] += float(((err * masks[w]).sum(1) / counts[w]).sum()) / len(noise)
    return sums


def load_focal(checkpoint: Path):
    """The checkpoint's policy and preprocessor, as ``lerobot-eval`` loads them; refuses a non-focal policy."""
    from ..analyze import load_policy

    policy, pre, _post = load_policy(checkpoint)
    if policy.config.type != "focal":
        raise SystemExit(f"tau_profile: {checkpoint} is a '{policy.config.type}' policy; the profile is defined for "
                         "focal's flow map only (diffusion has no one-step map to measure)")
    return policy, pre


def profile(policy, pre, root: Path, repo_id: str, frames: int = FRAMES, taus: tuple[float, ...] = TAUS) -> dict:
    """The one-step error profile of a loaded focal policy on a LeRobotDataset on disk (see the module doc). The
    first flow time is always the policy's own inference point ``anchor.eps``."""
    from lerobot.datasets.factory import resolve_delta_timestamps
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata

    eps = policy.config.anchor.eps
    taus = (eps, *(t for t in taus if t > eps))
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    ds = LeRobotDataset(repo_id, root=root, delta_timestamps=resolve_delta_timestamps(policy.config, meta))
    idx = np.unique(np.linspace(0, len(ds) - 1, min(frames, len(ds))).round().astype(int)).tolist()
    loader = torch.utils.data.DataLoader(torch.utils.data.Subset(ds, idx), batch_size=128, shuffle=False)
    gen = torch.Generator().manual_seed(NOISE_SEED)
    totals = {w: np.zeros(len(taus)) for w in WINDOWS}
    chunks = []
    with torch.inference_mode():
        for raw in loader:
            batch = pre(raw)
            noise = [torch.randn(batch["action"].shape, generator=gen) for _ in range(NOISE_DRAWS)]
            for w, sums in one_step_errors(policy, batch, taus, noise).items():
                totals[w] += sums
            chunks.append(batch["action"])
    m1 = torch.cat(chunks)
    h = policy.config.chunk_size
    return {"taus": list(taus), "frames": len(m1),
            **{w: [round(float(x) / len(m1), 5) for x in totals[w]] for w in WINDOWS},
            "reference": {"proximal": round(float((m1[:, :h] - m1[:, :h].mean(0)).pow(2).mean()), 5),
                          "macro": round(float((m1 - m1.mean(0)).pow(2).mean()), 5)}}


def render(done: dict[str, dict], scores: dict[str, float]) -> str:
    """Markdown: per task · method (mean over its seeds), the proximal-chunk error on the demos at each τ."""
    groups = _groups(done)
    taus = next(iter(done.values()))["train"]["taus"]
    md = ["# Where along the flow the one-step map is still wrong", "",
          "`lerobot-focal-bench tau-profile --out <grid>`: mean squared error of the one-step "
          "prediction f(M_τ, τ) = M_τ + (1 − τ)·v(M_τ, τ, o) against the expert chunk M_1, on the proximal "
          "(executed) chunk, in normalised action units; inference evaluates it at τ = ε (the first column). "
          "Mean over the method's seeds; each run on evenly spaced frames of its own demos with fixed noise. "
          "\"ref.\" is the variance of M_1 around the mean chunk: what predicting the average chunk would score.", "",
          "## On the demos (what the objective was fit to)", "",
          "| task · method | top-5 % | ref. | " + " | ".join(f"τ={t:g}" for t in taus) + " |",
          "|---|---|---|" + "---|" * len(taus)]
    for (task, method), runs in sorted(groups.items()):
        prof = np.mean([r["train"]["proximal"] for r in runs], axis=0)
        ref = np.mean([r["train"]["reference"]["proximal"] for r in runs])
        top5 = [scores[k] for k in _keys(done, task, method) if k in scores]
        md.append(f"| {task} · {method} | {np.mean(top5) * 100:.0f} | {ref:.3f} | " if top5 else
                  f"| {task} · {method} | – | {ref:.3f} | ")
        md[-1] += " | ".join(f"{x:.4f}" for x in prof) + " |"
    md += ["", "## At the inference point τ = ε, demos and held-out episodes", "",
           "| task · method | runs | proximal, demos | proximal, held-out | macro, demos | macro, held-out |",
           "|---|---|---|---|---|---|"]
    for (task, method), runs in sorted(groups.items()):
        cells = [np.mean([r[split][w][0] for r in runs]) for w in WINDOWS for split in ("train", "heldout")]
        md.append(f"| {task} · {method} | {len(runs)} | " + " | ".join(f"{x:.4f}" for x in cells) + " |")
    paired = [row for a, b in PAIRS if (row := _paired_row(done, a, b))]
    if paired:
        md += ["", "## Paired at τ = ε, same task and seed", "",
               "Geometric mean over the pairs of the first method's error over the second's, and the pairs where "
               "the first is lower.", "",
               "| methods | pairs | proximal, demos | proximal, held-out | macro, demos | macro, held-out |",
               "|---|---|---|---|---|---|", *paired, "",
               "The same ratio at every τ (proximal chunk, demos): where along the flow the gap opens.", "",
               "| methods | " + " | ".join(f"τ={t:g}" for t in taus) + " |", "|---|" + "---|" * len(taus),
               *(row for a, b in PAIRS if (row := _ratio_by_tau_row(done, a, b)))]
    return "\n".join(md) + "\n"


def _common(done: dict[str, dict], a: str, b: str) -> list[tuple[dict, dict]]:
    """(run of a, run of b) for every task and seed both methods were measured on."""
    runs = {tuple(k.split("|")): r for k, r in done.items()}
    return [(runs[(t, a, s)], runs[(t, b, s)]) for (t, m, s) in sorted(runs) if m == a and (t, b, s) in runs]


def _ratio(pairs: list[tuple[dict, dict]], split: str, window: str, i: int) -> tuple[float, int]:
    """Geometric mean over the pairs of a's error over b's at the i-th τ, and the pairs where a's is lower."""
    ea = np.maximum([ra[split][window][i] for ra, _ in pairs], 1e-12)
    eb = np.maximum([rb[split][window][i] for _, rb in pairs], 1e-12)
    return float(np.exp(np.mean(np.log(ea / eb)))), int((ea < eb).sum())


def _ratio_by_tau_row(done: dict[str, dict], a: str, b: str) -> str | None:
    pairs = _common(done, a, b)
    if not pairs:
        return None
    cells = [_ratio(pairs, "train", "proximal", i) for i in range(len(pairs[0][0]["train"]["taus"]))]
    return f"| {a} / {b} ({len(pairs)} pairs) | " + " | ".join(f"{r:.2f}×" for r, _ in cells) + " |"


def _paired_row(done: dict[str, dict], a: str, b: str) -> str | None:
    pairs = _common(done, a, b)
    if not pairs:
        return None
    cells = [_ratio(pairs, split, w, 0) for w in WINDOWS for split in ("train", "heldout")]
    return (f"| {a} / {b} | {len(pairs)} | "
            + " | ".join(f"{r:.2f}× ({lower} of {len(pairs)} lower)" for r, lower in cells) + " |")


def _groups(done: dict[str, dict]) -> dict[tuple[str, str], list[dict]]:
    groups: dict[tuple[str, str], list[dict]] = {}
    for key, r in done.items():
        task, method, _seed = key.split("|")
        groups.setdefault((task, method), []).append(r)
    return groups


def _keys(done: dict[str, dict], task: str, method: str) -> list[str]:
    return [k for k in done if k.split("|")[:2] == [task, method]]


def plot(done: dict[str, dict], path: Path) -> None:
    """One panel per task: the proximal-chunk error against τ, a colour per method (mean over seeds), on the
    demos (solid) and the held-out episodes (dotted)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = _groups(done)
    tasks = sorted({t for t, _m in groups})
    methods = sorted({m for _t, m in groups})
    fig, axes = plt.subplots(1, len(tasks), figsize=(3.6 * len(tasks), 3.2), squeeze=False, sharey=True)
    for ax, task in zip(axes[0], tasks, strict=True):
        for i, method in enumerate(methods):
            runs = groups.get((task, method))
            if not runs:
                continue
            taus = runs[0]["train"]["taus"]
            for split, style in (("train", "-"), ("heldout", ":")):
                ax.plot(taus, np.mean([r[split]["proximal"] for r in runs], axis=0), style, marker="o", ms=3,
                        color=f"C{i}", label=f"{method}, {'demos' if split == 'train' else 'held-out'}")
        ax.set_yscale("log")
        ax.set_title(task, fontsize=9)
        ax.set_xlabel("flow time τ (inference at ε)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("‖f(M_τ, τ) − M_1‖², proximal chunk")
    axes[0][-1].legend(fontsize=6)
    save_png(fig, path, dpi=100)


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-bench tau-profile")
    add_run_filters(p, "focal,focal_online,wo_las,wo_fco_las", "focal-family methods to measure")
    p.add_argument("--frames", type=int, default=FRAMES, help=f"frames per dataset (default {FRAMES})")
    args = p.parse_args(argv)
    if args.frames < 1:
        p.error(f"--frames must be at least 1, got {args.frames}")
    torch.set_num_threads(1)  # a side measurement: leave the cores to the grid it usually runs beside

    def measure(spec) -> dict:
        policy, pre = load_focal(checkpoint_of(spec.run_dir))  # once for both datasets
        return {split: profile(policy, pre, root, repo, args.frames) for split, root, repo in (
            ("train", spec.data.train_root, spec.data.train_repo_id),
            ("heldout", spec.data.heldout_root, spec.data.heldout_repo_id))} | {"frames_asked": args.frames}

    def progress(key: str, entry: dict) -> str:
        tr = entry["train"]
        return (f"{key}: proximal error at τ = {tr['taus'][0]:g}: {tr['proximal'][0]:.4f}, at τ = {tr['taus'][-1]:g}: "
                f"{tr['proximal'][-1]:.4f} (reference {tr['reference']['proximal']:.4f})")

    done = measure_runs("tau_profile", args, measure, lambda e: e.get("frames_asked") == args.frames, progress)
    if done is None:
        return 2
    if not done:
        print(f"tau_profile: the finished runs in {args.out / 'results.jsonl'} are not runs of the grid in "
              f"{args.out / 'grid.json'}; nothing measured, nothing written.", file=sys.stderr)
        return 2
    scores = {k: r.success_top_k for k, r in ResultsFile(args.out / "results.jsonl").ok().items()}
    (args.out / "tau_profile.md").write_text(render(done, scores))
    plot(done, args.out / "tau_profile.png")
    print(render(done, scores))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
