"""The batch file's keys: captures as folders and globs with per-capture kind and overrides, synthetic seeds, the
output root; the capture kind read from a folder's contents; named errors for what is malformed."""

import pytest
import yaml

from torchrefl.batch.batch_file import detect_kind, read_batch
from torchrefl.errors import ConfigError


def write_batch(tmp_path, doc):
    path = tmp_path / "batch.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_every_key_makes_the_tasks_it_describes(tmp_path):
    for name in ("b", "a"):
        (tmp_path / "scans" / name).mkdir(parents=True)
    (tmp_path / "base.yaml").write_text("seed: 1\n")
    path = write_batch(
        tmp_path,
        {
            "base": "base.yaml",
            "captures": ["scans/*", {"path": "scans/a", "kind": "mesh_views", "overrides": ["fit.iterations=5"]}],
            "synthetic_seeds": [3, 4],
            "overrides": ["fit.model=local"],
            "output": "out",
            "cpus_per_task": 2,
            "gpus_per_task": 0.5,
            "retries": 1,
        },
    )
    batch = read_batch(path)
    assert [t.name for t in batch.tasks] == ["a", "b", "a-2", "seed-3", "seed-4"]
    assert batch.base == str(tmp_path / "base.yaml") and batch.output == tmp_path / "out"
    assert (batch.cpus_per_task, batch.gpus_per_task, batch.retries) == (2.0, 0.5, 1)
    second = batch.tasks[2]
    assert second.capture == tmp_path / "scans" / "a" and second.output == tmp_path / "out" / "a-2"
    assert second.train_overrides() == [
        f"capture.path={tmp_path / 'scans' / 'a'}",
        "capture.kind=mesh_views",
        "fit.model=local",
        "fit.iterations=5",
        f"output.dir={tmp_path / 'out' / 'a-2'}",
    ]
    assert batch.tasks[3].train_overrides() == [
        "fit.model=local",
        "seed=3",
        f"output.dir={tmp_path / 'out' / 'seed-3'}",
    ]


def test_the_kind_comes_from_the_folder_and_a_folder_that_tells_none_is_named(tmp_path):
    for name, kind in (("scan.yaml", "cylindrical_scan"), ("scene.yaml", "mesh_views")):
        (tmp_path / kind).mkdir()
        (tmp_path / kind / name).write_text("")
        assert detect_kind(tmp_path / kind) == kind
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="cannot tell the capture kind of .*empty"):
        detect_kind(tmp_path / "empty")


@pytest.mark.parametrize(
    "doc, message",
    [
        ({"base": "default", "output": "o", "captures": ["x"], "workers": 2}, r"unknown key\(s\) \['workers'\]"),
        ({"base": "default", "captures": ["x"]}, "'output' is missing"),
        ({"base": "default", "output": "o"}, "nothing to fit"),
        ({"base": "default", "output": "o", "captures": ["nothing/*"]}, "'nothing/\\*' matches no folder"),
        ({"base": "default", "output": "o", "synthetic_seeds": ["one"]}, "synthetic_seeds must be integers"),
        ({"base": "default", "output": "o", "synthetic_seeds": [1], "cpus_per_task": 0}, "cpus_per_task must be > 0"),
    ],
)
def test_a_malformed_batch_file_is_a_named_error(tmp_path, doc, message):
    with pytest.raises(ConfigError, match=message):
        read_batch(write_batch(tmp_path, doc))
