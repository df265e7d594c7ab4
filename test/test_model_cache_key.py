"""The compiled kernels' cache key (model/compiled.py) covers every module of the model, sub-packages
included: a stale key would load machine code compiled from other sources, silently."""

from __future__ import annotations

import shutil
from pathlib import Path

from tdslip_ros.model import compiled


def _copy_of_the_model(tmp_path: Path) -> Path:
    model = tmp_path / "model"
    shutil.copytree(compiled.MODEL_DIR, model, ignore=shutil.ignore_patterns("__pycache__"))
    return model


def test_the_key_is_the_stamp_of_the_model_package() -> None:
    assert compiled.model_source_stamp() == compiled.source_stamp(compiled.MODEL_DIR)


def test_a_change_in_a_sub_package_changes_the_key(tmp_path: Path) -> None:
    model = _copy_of_the_model(tmp_path)
    before = compiled.source_stamp(model)
    assert compiled.source_stamp(model) == before  # the same sources give the same key
    stride = model / "plant" / "stride_kernels.py"
    stride.write_text(stride.read_text().replace("max_stance_time", "max_stance_time ", 1))
    assert compiled.source_stamp(model) != before


def test_a_module_moved_between_sub_packages_changes_the_key(tmp_path: Path) -> None:
    """Same names and contents, other places: the key is by relative path, not by file name."""
    model = _copy_of_the_model(tmp_path)
    before = compiled.source_stamp(model)
    (model / "policies" / "learned.py").rename(model / "stability" / "learned.py")
    assert compiled.source_stamp(model) != before
