"""Hub round trip through LeRobot's own API, against a local stand-in for the Hub (no network).

`LeRobotDataset.push_to_hub` talks to the Hub through `HfApi` (create_repo, upload_folder,
create_tag, ...) and `DatasetCard.push_to_hub`; loading by repo id lists the repo's refs (the
`v3.0` tag) and calls `snapshot_download`. `FakeHub` implements exactly those calls on a local
folder: uploads are copied in (honouring allow / ignore patterns), a tag freezes a copy of the
branch, downloads copy a tagged revision out. A real push needs `hf auth login`.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect import CollectConfig, collect
from lerobot_bavo.datasets.hub import load_bavo_dataset, push_dataset

REPO = "tester/bavo_hub"


def _not_found(message: str):
    import httpx
    from huggingface_hub.errors import RevisionNotFoundError

    return RevisionNotFoundError(message, response=httpx.Response(404, request=httpx.Request("GET", "https://hub.invalid")))


class FakeHub:
    def __init__(self, root: Path):
        self.root = root
        self.calls: list[tuple] = []

    def branch_dir(self, repo_id: str, revision: str | None = None) -> Path:
        return self.root / repo_id / "refs" / (revision or "main")

    def tags(self, repo_id: str) -> list[str]:
        base = self.root / repo_id / "tags"
        return sorted(p.name for p in base.iterdir()) if base.exists() else []

    # --- the HfApi surface LeRobot uses
    def api(self, *args, **kwargs):
        hub = self

        class FakeHfApi:
            def create_repo(self, repo_id, private=None, repo_type=None, exist_ok=False, **kw):
                hub.calls.append(("create_repo", repo_id, repo_type, private))
                hub.branch_dir(repo_id).mkdir(parents=True, exist_ok=True)

            def create_branch(self, repo_id, branch, revision=None, repo_type=None, exist_ok=False, **kw):
                hub.calls.append(("create_branch", repo_id, branch))
                hub.branch_dir(repo_id, branch).mkdir(parents=True, exist_ok=True)

            def upload_folder(self, repo_id, folder_path, repo_type=None, revision=None, allow_patterns=None,
                              ignore_patterns=None, **kw):
                from huggingface_hub.utils import filter_repo_objects

                hub.calls.append(("upload_folder", repo_id, repo_type, revision))
                folder = Path(folder_path)
                files = [str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()]
                dst = hub.branch_dir(repo_id, revision)
                for rel in filter_repo_objects(
                    files, allow_patterns=allow_patterns, ignore_patterns=ignore_patterns
                ):
                    (dst / rel).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(folder / rel, dst / rel)

            upload_large_folder = upload_folder

            def delete_tag(self, repo_id, tag, repo_type=None, **kw):
                hub.calls.append(("delete_tag", repo_id, tag))
                path = hub.root / repo_id / "tags" / tag
                if not path.exists():
                    raise _not_found(f"no tag {tag}")
                shutil.rmtree(path)

            def create_tag(self, repo_id, tag, revision=None, repo_type=None, **kw):
                hub.calls.append(("create_tag", repo_id, tag, repo_type))
                shutil.copytree(hub.branch_dir(repo_id, revision), hub.root / repo_id / "tags" / tag)

            def list_repo_refs(self, repo_id, repo_type=None, **kw):
                return SimpleNamespace(branches=[SimpleNamespace(name="main")],
                                       tags=[SimpleNamespace(name=t) for t in hub.tags(repo_id)])

        return FakeHfApi()

    def push_card(self, card, repo_id, repo_type=None, revision=None, **kw):
        self.calls.append(("card", repo_id, repo_type))
        (self.branch_dir(repo_id, revision) / "README.md").write_text(str(card))

    def snapshot_download(self, repo_id, repo_type=None, revision=None, local_dir=None, cache_dir=None,
                          allow_patterns=None, ignore_patterns=None, **kw):
        from huggingface_hub.utils import filter_repo_objects

        self.calls.append(("download", repo_id, revision))
        src = self.root / repo_id / "tags" / revision if revision in self.tags(repo_id) else None
        if src is None:
            raise _not_found(f"{repo_id}@{revision} not found")
        dst = (
            Path(local_dir)
            if local_dir is not None
            else Path(cache_dir) / repo_id.replace("/", "--") / revision
        )
        files = [str(p.relative_to(src)) for p in src.rglob("*") if p.is_file()]
        for rel in filter_repo_objects(files, allow_patterns=allow_patterns, ignore_patterns=ignore_patterns):
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src / rel, dst / rel)
        return str(dst)


@pytest.fixture
def hub(tmp_path, monkeypatch):
    import huggingface_hub
    import lerobot.datasets.dataset_metadata as md
    import lerobot.datasets.lerobot_dataset as ld
    import lerobot.datasets.utils as lu

    fake = FakeHub(tmp_path / "hub")
    monkeypatch.setattr(ld, "HfApi", fake.api)
    monkeypatch.setattr(lu, "HfApi", fake.api)
    monkeypatch.setattr(
        huggingface_hub.DatasetCard, "push_to_hub", lambda card, *a, **kw: fake.push_card(card, *a, **kw)
    )
    monkeypatch.setattr(ld, "snapshot_download", fake.snapshot_download)
    monkeypatch.setattr(md, "snapshot_download", fake.snapshot_download)
    monkeypatch.setattr(md, "HF_LEROBOT_HOME", tmp_path / "lerobot_home")
    monkeypatch.setattr(md, "HF_LEROBOT_HUB_CACHE", tmp_path / "lerobot_home" / "hub")
    monkeypatch.setattr(ld, "HF_LEROBOT_HUB_CACHE", tmp_path / "lerobot_home" / "hub")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    return fake


def test_push_to_hub_and_load_back_by_repo_id(hub, tmp_path):
    root = tmp_path / "local" / "bavo_hub"
    collect(
        CollectConfig(
            task="cube_handoff",
            condition="stage",
            episodes=2,
            repo_id=REPO,
            root=root,
            workers=0,
            settings=S.ObservationSettings(48, 64, 32),
            episode_length=20,
            keep_failures=True,
            progress=False,
        )
    )
    (root / ".bavo_staging").mkdir()
    (root / ".bavo_staging" / "leftover.npz").write_bytes(b"x")  # must not be uploaded

    push_dataset(root, REPO)
    names = [c[0] for c in hub.calls]
    assert names[:2] == ["create_repo", "upload_folder"] and "card" in names
    assert ("create_tag", REPO, "v3.0", "dataset") in hub.calls  # the tag loading by repo id needs
    pushed = hub.root / REPO / "tags" / "v3.0"
    assert (pushed / "meta" / "info.json").exists() and (pushed / "meta" / "bavo_collection.json").exists()
    assert list((pushed / "videos").rglob("*.mp4")) and list((pushed / "data").rglob("*.parquet"))
    assert not (pushed / ".bavo_staging").exists()
    card = (pushed / "README.md").read_text()
    assert "BAVO-Bench demonstrations" in card and "simulator-exact" in card and "LeRobot" in card
    assert "bavo-bench" in card and "task_categories" in card  # LeRobot's card metadata kept

    # Load by repo id, nothing local: LeRobot resolves the v3.0 tag and downloads it.
    ds = load_bavo_dataset(REPO, n_points=32)
    assert ds.num_episodes == 2 and len(ds) == 40
    assert ("download", REPO, "v3.0") in hub.calls
    assert ds[25][S.OBS_IMAGE].shape == (3, 48, 64)

    # The pushed folder itself loads offline with a local root.
    ds2 = load_bavo_dataset(REPO, root=pushed)
    assert ds2.num_episodes == 2
    assert float(ds2[5][S.OBS_POINT_CLOUD].sum()) == pytest.approx(float(ds[5][S.OBS_POINT_CLOUD].sum()))


def test_loading_a_repo_without_the_version_tag_fails_clearly(hub, tmp_path):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    hub.api().create_repo("tester/untagged", repo_type="dataset")
    with pytest.raises(Exception, match="(?i)version|tag"):
        LeRobotDataset("tester/untagged")
