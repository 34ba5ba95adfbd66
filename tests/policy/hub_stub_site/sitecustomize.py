"""Stand in for the Hub in a real ``lerobot-train --policy.push_to_hub=true`` subprocess (test support).

The one stub of the Hub path, named as such: the network calls — ``HfApi.create_repo`` / ``upload_folder`` (what
LeRobot's ``push_model_to_hub``, the processors' ``push_to_hub`` and ``LeRobotDataset.push_to_hub`` make),
``RepoCard.push_to_hub`` (the dataset card), ``RepoCard.validate`` (the Hub validates the card's YAML; here it is
parsed locally) and the dataset's version tag calls — are replaced, only when
``FOCAL_HUB_STUB_DIR`` is set, by a copy of what would be uploaded into ``$FOCAL_HUB_STUB_DIR/<repo_id>``
(honouring the call's allow/ignore patterns). Everything before the upload — saving weights, config, processors,
writing the model card, finalising the dataset — is LeRobot's and the plugin's real code.
"""

import os

if os.environ.get("FOCAL_HUB_STUB_DIR"):
    import fnmatch
    import shutil
    import types
    from pathlib import Path

    from huggingface_hub import HfApi, RepoCard

    _ROOT = Path(os.environ["FOCAL_HUB_STUB_DIR"])

    def _create_repo(self, repo_id, **kwargs):
        (_ROOT / repo_id).mkdir(parents=True, exist_ok=True)
        return types.SimpleNamespace(repo_id=repo_id, url=f"stub://{repo_id}")

    def _upload_folder(self, *, repo_id, folder_path, allow_patterns=None, ignore_patterns=None, **kwargs):
        src, dst = Path(folder_path), _ROOT / repo_id
        allow = [allow_patterns] if isinstance(allow_patterns, str) else allow_patterns
        ignore = [ignore_patterns] if isinstance(ignore_patterns, str) else (ignore_patterns or [])
        for f in src.rglob("*"):
            rel = f.relative_to(src).as_posix()
            if not f.is_file() or (allow and not any(fnmatch.fnmatch(rel, p) for p in allow)):
                continue
            if any(fnmatch.fnmatch(rel, p) or rel.startswith(p.rstrip("*")) and p.endswith("/") for p in ignore):
                continue
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dst / rel)
        return types.SimpleNamespace(repo_url=types.SimpleNamespace(url=f"stub://{repo_id}"), commit_url="stub://")

    def _push_card(self, repo_id, **kwargs):
        (_ROOT / repo_id).mkdir(parents=True, exist_ok=True)
        (_ROOT / repo_id / "README.md").write_text(str(self))
        return "stub://"

    def _validate(self, repo_type=None):
        import yaml

        meta = yaml.safe_load(str(self).split("---")[1])
        if not isinstance(meta, dict) or "license" not in meta:
            raise ValueError(f"card metadata without a license: {meta!r}")

    HfApi.create_repo = _create_repo
    HfApi.upload_folder = _upload_folder
    HfApi.create_tag = HfApi.delete_tag = HfApi.create_branch = lambda self, *a, **k: None
    RepoCard.push_to_hub = _push_card
    RepoCard.validate = _validate
