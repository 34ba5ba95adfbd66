"""Training presets shipped with the package, for `lerobot-train --config_path=...`.

    lerobot-train --config_path=$(lerobot-focal-config cpu) --dataset.repo_id=<user/dataset>
    lerobot-focal-config --list

``paper`` is the paper's hyper-parameter table (GPU); ``cpu`` keeps the method and shrinks the U-Net for
point clouds on a CPU; ``cpu_state`` is the small network for low-dimensional inputs (state + object poses).
In a source checkout the same files are reachable as ``configs/*.json``. This module imports nothing of
LeRobot, so the command answers instantly.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from lerobot_focal.console import doc_parser

PRESETS = {"paper": "focal_paper.json", "cpu": "focal_cpu.json", "cpu_state": "focal_cpu_state.json"}


def preset_path(name: str) -> Path:
    """Filesystem path of a shipped preset (by short name, e.g. "cpu", or file name)."""
    file = PRESETS.get(name, name if name.endswith(".json") else f"{name}.json")
    if file not in PRESETS.values():
        raise KeyError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    path = Path(str(resources.files(__name__).joinpath(file)))
    if not path.is_file():
        raise FileNotFoundError(f"preset {file} is missing from the installed package at {path}; reinstall it")
    return path


def main(argv: list[str] | None = None) -> int:
    p = doc_parser(__doc__, "lerobot-focal-config")
    p.add_argument("name", nargs="?", help=f"one of {', '.join(PRESETS)}")
    p.add_argument("--list", action="store_true", help="list the presets and their paths")
    args = p.parse_args(argv)
    if args.list or not args.name:
        for name in PRESETS:
            print(f"{name:10s} {preset_path(name)}")
        return 0
    try:
        print(preset_path(args.name))
    except KeyError as err:
        p.error(str(err.args[0]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
