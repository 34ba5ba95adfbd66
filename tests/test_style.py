"""The code's style, checked: `ruff check` over the whole repository with ruff.toml's rules."""

import importlib.util
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.subprocess  # ruff's own binary, about a second


def test_ruff_check_passes_on_the_repository():
    if importlib.util.find_spec("ruff") is None:
        pytest.fail("ruff is not installed in this environment: install the dev extra "
                    "(`.venv/bin/pip install -e '.[dev]'`, or ./scripts/setup.sh, which does)")
    proc = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise", "."],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    if proc.returncode == 0:
        return
    findings = [line for line in proc.stdout.splitlines() if line.count(":") >= 3 and not line.startswith(" ")]
    per_file = Counter(line.split(":", 1)[0] for line in findings)
    assert proc.returncode == 1 and findings, f"ruff did not run:\n{proc.stdout}\n{proc.stderr}"
    pytest.fail(
        f"ruff check found {len(findings)} problems (rules: ruff.toml) in "
        + ", ".join(f"{path} ({n})" for path, n in sorted(per_file.items()))
        + ":\n" + "\n".join(findings)
        + "\n\nFix them: `.venv/bin/ruff check --fix <file>` fixes those marked [*] (import order, ...); wrap long "
        "lines (E501, 120 characters) by hand; where a rule is broken on purpose, say why on the line: "
        "`# noqa: BLE001 - the reason`. Do not run `ruff format` over the codebase.",
        pytrace=False,
    )
