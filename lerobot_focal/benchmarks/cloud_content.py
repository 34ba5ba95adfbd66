"""What the 512 points of a MetaWorld cloud fall on: the table and its rim, the arm, or the task's objects.

    lerobot-focal-bench cloud-content [--tasks pick-place sweep-into ...] [--resets 5] [--out docs/benchmarks]

Farthest-point sampling spreads its points evenly over whatever the crop box keeps, so static scenery inside
the box takes points in proportion to its extent, not to its use: a table top a metre wide outbids a 4 cm puck.
Drawn sites count as what they are attached to: MetaWorld's goal marker (on the world body) as a task object.
This compares the env's crop (the table top and its rim cropped away) with the box the project used before,
which kept both. Each point is attributed to the body its ray hit (the ray-cast sensor's per-pixel geom and
site ids, at the point's nearest back-projected pixel). Writes ``cloud_content.{md,json,png}`` and a picture
of one cloud under each crop, ``cloud_content_example.png``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lerobot_focal.console import doc_parser
from lerobot_focal.figures import save_png

#: The crop box the MetaWorld env used before the table crop: table top and rim inside.
PREVIOUS_BOX = {"workspace_low": (-0.6, 0.2, -0.02), "workspace_high": (0.6, 1.05, 0.75), "table_clearance": None}
#: Static bodies of every MetaWorld scene: the table (with its legs) and the 12 cm rim around its top.
SCENERY_BODIES = ("tablelink", "RetainingWall")
CATEGORIES = ("table and rim", "arm", "task objects")
DEV_TASKS = ("pick-place", "sweep-into", "disassemble", "push-wall", "basketball")


def _categories(model) -> np.ndarray:
    """Category index of every body: scenery, the Sawyer arm (everything under the hand's root body) or object."""
    import mujoco

    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in range(model.nbody)]
    arm_root = model.body_rootid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "hand")]
    out = np.full(model.nbody, 2)
    for b, name in enumerate(names):
        if name in SCENERY_BODIES or names[model.body_rootid[b]] in SCENERY_BODIES:
            out[b] = 0
        elif model.body_rootid[b] == arm_root:
            out[b] = 1
    return out


def attributed_cloud(task: str, seed: int, **crop) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The env's cloud after ``reset(seed)``, each point's category index, and which points lie within 4 cm of
    MetaWorld's own object position."""
    from lerobot_focal.envs.focal_metaworld import FocalMetaworldEnvConfig

    env = FocalMetaworldEnvConfig(task=task, obs_type="pointcloud", render_videos=False, **crop).make_single_env()
    try:
        obs, _ = env.reset(seed=seed)
        cloud = obs["pointcloud"]
        model, data = env._env.model, env._env.data
        camera = env._pc_sensor.camera
        depth = camera.render(data).ravel()  # the frame the cloud was made from (same state, same rays)
        # the body each pixel's ray hit: a geom's, or a drawn site's (MetaWorld's goal marker is on the world body)
        sites, geoms = camera.last_site_ids.ravel(), camera.last_geom_ids.ravel()
        bodies = np.where(sites >= 0, model.site_bodyid[np.maximum(sites, 0)], model.geom_bodyid[np.maximum(geoms, 0)])
        pose = camera.pose(data).matrix()
        points = (camera.intrinsics.pixel_rays() * depth[:, None]) @ pose[:3, :3].T + pose[:3, 3]
        bounds = env.pointcloud_spec.bounds
        seen = (depth > 0) & np.all((points >= bounds.low) & (points <= bounds.high), axis=1)
        points, bodies = points[seen], bodies[seen]
        nearest = np.array([int(np.argmin(((points - p) ** 2).sum(1))) for p in cloud])
        category = _categories(model)[bodies[nearest]]
        near_object = np.linalg.norm(cloud - env.last_raw_obs[4:7], axis=1) < 0.04
    finally:
        env.close()
    return cloud, category, near_object


def cloud_content(task: str, seed: int, **crop) -> dict[str, float]:
    """Share of the cloud's points on each category, and points within 4 cm of MetaWorld's object position."""
    _, category, near_object = attributed_cloud(task, seed, **crop)
    shares = {name: float((category == i).mean()) for i, name in enumerate(CATEGORIES)}
    return {**shares, "points_near_object": int(near_object.sum())}


def measure(tasks: list[str], resets: int) -> list[dict]:
    rows = []
    for task in tasks:
        for crop_name, crop in (("previous box", PREVIOUS_BOX), ("env default", {})):
            runs = [cloud_content(task, seed, **crop) for seed in range(resets)]
            row = {"task": task, "crop": crop_name, "resets": resets}
            row.update({k: float(np.median([r[k] for r in runs])) for k in runs[0]})
            rows.append(row)
            print(f"{task:<12} {crop_name:<13} " + "  ".join(
                f"{k} {100 * row[k]:4.0f} %" for k in CATEGORIES) + f"  points within 4 cm of the object "
                f"{row['points_near_object']:.0f}", flush=True)
    return rows


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [f"{r['task']}\n{r['crop']}" for r in rows]
    fig, ax = plt.subplots(figsize=(1.1 * len(rows) + 2, 4))
    bottom = np.zeros(len(rows))
    for name, colour in zip(CATEGORIES, ("0.7", "tab:blue", "tab:orange"), strict=True):
        share = np.array([100 * r[name] for r in rows])
        ax.bar(labels, share, bottom=bottom, color=colour, label=name)
        bottom += share
    ax.set_ylabel("% of the 512 points (median over resets)")
    ax.set_title("What a MetaWorld cloud's points fall on")
    ax.tick_params(axis="x", labelsize=7)
    ax.legend(loc="upper right", fontsize=8)
    save_png(fig, path, dpi=120)


def _plot_example(task: str, path: Path) -> None:
    """One cloud of ``task`` (reset seed 0) seen from the side, under each crop, coloured by what it fell on."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(10, 4.5))
    for i, (name, crop) in enumerate((("previous box", PREVIOUS_BOX), ("env default", {}))):
        cloud, category, _ = attributed_cloud(task, 0, **crop)
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        for c, colour in enumerate(("0.6", "tab:blue", "tab:orange")):
            pts = cloud[category == c]
            ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=4, color=colour, label=f"{CATEGORIES[c]} ({len(pts)})")
        ax.set_title(f"{task}, {name}", fontsize=9)
        ax.view_init(elev=25, azim=-60)
        lo, hi = PREVIOUS_BOX["workspace_low"], PREVIOUS_BOX["workspace_high"]
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        ax.legend(fontsize=7, loc="upper left")
    save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = doc_parser(__doc__, "lerobot-focal-bench cloud-content")
    parser.add_argument("--tasks", nargs="+", default=list(DEV_TASKS))
    parser.add_argument("--resets", type=int, default=5, help="object placements (reset seeds 0..N-1) per task")
    parser.add_argument("--out", type=Path, default=Path("docs/benchmarks"))
    args = parser.parse_args(argv)
    rows = measure(args.tasks, args.resets)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "cloud_content.json").write_text(json.dumps({"previous_box": PREVIOUS_BOX, "rows": rows}, indent=2))
    lines = [
        "# What the 512 points of a MetaWorld cloud fall on",
        "",
        f"`lerobot-focal-bench cloud-content --resets {args.resets}`: camera corner2, 128×128 rays, 1 cm voxels, "
        "farthest-point sampling to 512 points; median over reset seeds. *previous box*: "
        f"{PREVIOUS_BOX['workspace_low']} to {PREVIOUS_BOX['workspace_high']}, table kept; *env default*: the "
        "table top and its rim cropped away.",
        "",
        "| task | crop | table and rim | arm | task objects | points within 4 cm of the object |",
        "|---|---|---|---|---|---|",
    ]
    lines += [f"| {r['task']} | {r['crop']} | " + " | ".join(f"{100 * r[k]:.0f} %" for k in CATEGORIES)
              + f" | {r['points_near_object']:.0f} |" for r in rows]
    (args.out / "cloud_content.md").write_text("\n".join(lines) + "\n")
    _plot(rows, args.out / "cloud_content.png")
    _plot_example(args.tasks[0], args.out / "cloud_content_example.png")
    print(f"wrote {args.out}/cloud_content.md, .json, .png and cloud_content_example.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
