"""Finished training stages of ``seal fit behavior``, kept so that an interrupted fit goes on where it stopped.

A fit trains four stages per seed (two pre-trainings, each then fine-tuned on the crash set): 46.5 min in all for
the decisive preset on the machine of session 27, and a session that ended part way lost all of it. After each stage
its network, prototypes and training-log rows are written to ``<out>/stages/<variant>-s<seed>.pt`` (a behaviour model
file), beside ``stages/settings.json``: the fingerprint (`seal.core.chunked.fingerprint`) of the fit's config, the
dataset and the sizes of its samples. A fit started again with the same settings loads the stages that are there
instead of training them; every stage seeds its own training (`seal.models.behavior.train`), so the result is the
model an uninterrupted fit writes. A fit with other settings starts over (the stage files are removed first). The
folder is removed once the fit has written its report.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_bytes
from seal.core.chunked import fingerprint
from seal.models.behavior.model import BehaviorFileError, BehaviorModel

logger = logging.getLogger(__name__)

STAGES_DIR = "stages"
SETTINGS_FILE = "settings.json"
LOG_KEY = "train_log"
"""Key of the stage's training-log rows in a stage file's info (not in the variant files the fit writes)."""


class StageStore:
    """The ``stages`` folder of one fit (see the module docstring).

    Args:
        out: the fit's output folder.
        settings: JSON-safe description of everything the stages depend on; stage files written under other
            settings are removed.
    """

    def __init__(self, out: str | Path, settings: dict[str, Any]) -> None:
        self.folder = Path(out) / STAGES_DIR
        self.loaded: list[str] = []
        """Names (``<variant>-s<seed>``) of the stages loaded instead of trained, in order."""
        text = fingerprint(settings)
        path = self.folder / SETTINGS_FILE
        stored = path.read_text() if path.is_file() else None
        if stored != text:
            if self.folder.exists():
                logger.info("fit behavior: %s holds stages of other settings: starting over", self.folder)
                shutil.rmtree(self.folder)
            self.folder.mkdir(parents=True)
            atomic_write_bytes(path, text.encode())

    def _path(self, variant: str, seed: int) -> Path:
        return self.folder / f"{variant}-s{seed}.pt"

    def load(self, variant: str, seed: int) -> tuple[BehaviorModel, list[dict[str, Any]]] | None:
        """The finished stage's model and its log rows, or None when it is not there (or unreadable: trained
        again)."""
        path = self._path(variant, seed)
        if not path.is_file():
            return None
        try:
            model = BehaviorModel.load(path)
        except (BehaviorFileError, FileNotFoundError) as exc:
            logger.warning("fit behavior: stage file %s does not load (%s): training that stage again", path, exc)
            return None
        rows = list(model.info.pop(LOG_KEY, []))
        self.loaded.append(path.stem)
        logger.info("fit behavior: stage %s loaded from %s (finished before)", path.stem, path)
        return model, rows

    def save(self, variant: str, seed: int, model: BehaviorModel, rows: list[dict[str, Any]]) -> None:
        """Keep a finished stage (atomic write)."""
        stage = BehaviorModel(model.config, model.net, model.prototypes, None, model.lora,
                              {**model.info, LOG_KEY: rows})
        stage.save(self._path(variant, seed))
        self._path(variant, seed).with_suffix(".json").unlink(missing_ok=True)  # the readable copy is not needed

    def finish(self) -> None:
        """Remove the folder (the fit's own files now hold every stage)."""
        shutil.rmtree(self.folder, ignore_errors=True)
