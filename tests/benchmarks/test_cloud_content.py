"""`lerobot-focal-bench cloud-content` on a real MetaWorld scene: points attributed to what the rays hit."""

import json

import pytest

pytest.importorskip("metaworld")


def test_cloud_content_attributes_points_and_shows_the_table_crop(tmp_path):
    from lerobot_focal.benchmarks.cloud_content import CATEGORIES, main

    assert main(["--tasks", "pick-place", "--resets", "1", "--out", str(tmp_path)]) == 0
    rows = {r["crop"]: r for r in json.loads((tmp_path / "cloud_content.json").read_text())["rows"]}
    for row in rows.values():
        assert sum(row[c] for c in CATEGORIES) == pytest.approx(1.0)
    before, now = rows["previous box"], rows["env default"]
    assert before["table and rim"] > 0.5 and now["table and rim"] == 0.0
    assert now["arm"] > before["arm"] and now["points_near_object"] > before["points_near_object"]
    assert "| pick-place | env default | 0 % |" in (tmp_path / "cloud_content.md").read_text()
    assert (tmp_path / "cloud_content.png").stat().st_size > 1000
    assert (tmp_path / "cloud_content_example.png").stat().st_size > 1000
