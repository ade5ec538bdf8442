"""Dataset importers: ``glimpse import DATASET SOURCE SCENE_DIR`` writes a dataset's sequence as a
glimpse-scene/1 folder through the scene writer, one module per dataset (docs/datasets.md)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from glimpse.errors import GlimpseError
from glimpse.importers.common import ImportOptions
from glimpse.importers.emdb import import_emdb
from glimpse.importers.hi4d import import_hi4d
from glimpse.importers.neuman import import_neuman
from glimpse.importers.panoptic import import_panoptic
from glimpse.importers.zju_mocap import import_zju_mocap

Importer = Callable[[Path, Path, ImportOptions], Path]
DATASETS: dict[str, Importer] = {"zju-mocap": import_zju_mocap, "panoptic": import_panoptic, "emdb": import_emdb,
                                 "hi4d": import_hi4d, "neuman": import_neuman}


def import_dataset(dataset: str, source: Path, scene_dir: Path, options: ImportOptions) -> Path:
    """Import ``source`` (the dataset's folder, or one sequence's) into ``scene_dir``; returns the scene."""
    if dataset not in DATASETS:
        raise GlimpseError(f"unknown dataset {dataset!r}; Glimpse imports {', '.join(sorted(DATASETS))}")
    if not Path(source).is_dir():
        raise GlimpseError(f"{source}: no such folder")
    return DATASETS[dataset](Path(source), Path(scene_dir), options)
