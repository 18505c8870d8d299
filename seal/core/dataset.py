"""Dataset store: one directory = ``manifest.json`` + ``shards/shard-NNNNN.npz``.

* Shards are columnar ``.npz`` files (numpy only, loaded with ``allow_pickle=False``): all agents' tracks of
  all scenarios of the shard concatenated, plus offsets, ids, roads (deduplicated JSON) and metadata (JSON).
* Every file is written atomically. ``manifest.json`` is written last, so a directory without it is not a
  dataset (an interrupted build: ``build.json`` records the build parameters and the shards already done,
  and `DatasetBuilder` resumes from it).
* The manifest records the schema version, provenance, counts, splits and each shard's size and sha256;
  loading checks them and names the file that is missing, truncated or corrupt.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import zipfile
from collections import Counter
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.atomic import atomic_write, atomic_write_json
from seal.core.errors import SealError
from seal.core.road import RoadDescription, RoadError
from seal.core.scenario import GroupError, Scenario, ScenarioError, group_of

SCHEMA_VERSION = 1
MANIFEST = "manifest.json"
BUILD_STATE = "build.json"
SHARD_DIR = "shards"
FORMAT = "seal-dataset"


class DatasetError(SealError, RuntimeError):
    """A dataset directory or file cannot be used; the message names the file and what to do."""


# --------------------------------------------------------------------------------------------- shards
_SHARD_FIELDS = ("file", "n_scenarios", "bytes", "sha256")


def _check_totals(path: Path, manifest: dict[str, Any]) -> None:
    """Every shard entry complete, and the scenario count equal to the shards' sum: a damaged manifest (an entry
    lost or edited) fails here instead of silently loading fewer scenarios."""
    shards, counts = manifest["shards"], manifest["counts"]
    if not isinstance(shards, list) or not shards:
        raise DatasetError(f"{path}: field 'shards' must be a non-empty list of shard entries")
    for i, entry in enumerate(shards):
        missing = [k for k in _SHARD_FIELDS if not isinstance(entry, dict) or k not in entry]
        if missing:
            raise DatasetError(f"{path}: shards[{i}] lacks field(s) {missing}")
    if not isinstance(counts, dict) or not isinstance(counts.get("scenarios"), int):
        raise DatasetError(f"{path}: field 'counts' must hold the integer 'scenarios'")
    held = sum(int(entry["n_scenarios"]) for entry in shards)
    if held != counts["scenarios"]:
        raise DatasetError(
            f"{path}: counts.scenarios is {counts['scenarios']} but the shards hold {held}; the manifest is damaged "
            "(rebuild the dataset, or restore manifest.json)"
        )


def encode_shard(scenarios: Sequence[Scenario]) -> dict[str, np.ndarray]:
    """Columnar arrays for a list of scenarios (see the module docstring)."""
    if not scenarios:
        raise ValueError("a shard needs at least one scenario")
    road_json: dict[str, int] = {}
    road_index = []
    for s in scenarios:
        key = s.road.to_json()
        road_index.append(road_json.setdefault(key, len(road_json)))
    counts = np.array([s.n_agents for s in scenarios], dtype=np.int64)
    return {
        "schema_version": np.array(SCHEMA_VERSION, dtype=np.int64),
        "scenario_ids": np.array([s.scenario_id for s in scenarios]),
        "agent_offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        "tracks": np.concatenate([s.tracks for s in scenarios]).astype(np.float32),
        "agent_ids": np.concatenate([s.agent_ids for s in scenarios]).astype(np.int64),
        "agent_types": np.array([t for s in scenarios for t in s.agent_types]),
        "ego_ids": np.array([s.ego_id for s in scenarios], dtype=np.int64),
        "adv_ids": np.array([s.adv_id for s in scenarios], dtype=np.int64),
        "road_index": np.array(road_index, dtype=np.int64),
        "roads_json": np.array(list(road_json)),
        "sources": np.array([s.source for s in scenarios]),
        "metadata_json": np.array([json.dumps(dict(s.metadata), sort_keys=True) for s in scenarios]),
    }


_SHARD_KEYS = (
    "schema_version", "scenario_ids", "agent_offsets", "tracks", "agent_ids", "agent_types", "ego_ids",
    "adv_ids", "road_index", "roads_json", "sources", "metadata_json",
)


def write_shard(path: Path, scenarios: Sequence[Scenario]) -> dict[str, Any]:
    """Atomically write a shard; return its manifest entry (file, n_scenarios, bytes, sha256)."""
    buf = io.BytesIO()
    # Any: numpy's stubs let a ``**dict`` of arrays collide with the ``allow_pickle: bool`` keyword.
    arrays: dict[str, Any] = encode_shard(scenarios)
    np.savez_compressed(buf, **arrays)
    data = buf.getvalue()
    atomic_write(path, lambda f: f.write(data))
    return {"n_scenarios": len(scenarios), "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}


def read_shard(
    path: Path, expected: dict[str, Any] | None = None, wanted: set[str] | None = None
) -> list[Scenario]:
    """Load the scenarios of one shard (only those whose id is in ``wanted``, when given), checking size and
    checksum against ``expected`` when given. Scenarios left out are not decoded: picking a split's few hundred
    scenarios from thousands then costs the decompression, not a `Scenario` per scenario of the shard."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"shard file {path} is missing; the dataset is incomplete, rebuild it") from None
    if expected is not None:
        if len(data) != expected["bytes"]:
            raise DatasetError(
                f"shard file {path} is truncated or corrupt: {len(data)} bytes, manifest says {expected['bytes']}"
            )
        if hashlib.sha256(data).hexdigest() != expected["sha256"]:
            raise DatasetError(f"shard file {path} is corrupt: its sha256 does not match the manifest")
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {k: z[k] for k in _SHARD_KEYS}
    except KeyError as exc:
        raise DatasetError(f"shard file {path} lacks array {exc.args[0]!r}; not a seal shard") from None
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        raise DatasetError(f"shard file {path} is truncated or corrupt ({type(exc).__name__}: {exc})") from None
    version = int(arrays["schema_version"])
    if version != SCHEMA_VERSION:
        raise DatasetError(f"shard file {path} has schema version {version}; this seal reads {SCHEMA_VERSION}")
    try:
        roads = [RoadDescription.from_json(str(j)) for j in arrays["roads_json"]]
        out = []
        offsets = arrays["agent_offsets"]
        for i, sid in enumerate(arrays["scenario_ids"]):
            if wanted is not None and str(sid) not in wanted:
                continue
            a, b = int(offsets[i]), int(offsets[i + 1])
            out.append(
                Scenario(
                    scenario_id=str(sid),
                    tracks=arrays["tracks"][a:b],
                    agent_ids=arrays["agent_ids"][a:b],
                    agent_types=tuple(arrays["agent_types"][a:b].tolist()),
                    ego_id=int(arrays["ego_ids"][i]),
                    adv_id=int(arrays["adv_ids"][i]),
                    road=roads[int(arrays["road_index"][i])],
                    source=str(arrays["sources"][i]),
                    metadata=json.loads(str(arrays["metadata_json"][i])),
                )
            )
    except (ScenarioError, RoadError) as exc:
        raise DatasetError(f"shard file {path}: {exc}") from None
    return out


# --------------------------------------------------------------------------------------------- dataset
class Dataset:
    """A finished dataset directory. Open with `Dataset.open`; scenarios load lazily per shard."""

    def __init__(self, root: Path, manifest: dict[str, Any]) -> None:
        self.root = root
        self.manifest = manifest

    @classmethod
    def open(cls, root: str | Path) -> Dataset:
        root = Path(root)
        path = root / MANIFEST
        if not path.exists():
            if (root / BUILD_STATE).exists():
                raise DatasetError(
                    f"{root} is an unfinished build (no {MANIFEST}, but {BUILD_STATE} exists); "
                    "re-run the same `seal data generate` command to resume it"
                )
            raise DatasetError(f"{root} is not a seal dataset: {path} not found")
        try:
            manifest = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise DatasetError(f"{path} is not valid JSON ({exc})") from None
        if not isinstance(manifest, dict):
            raise DatasetError(f"{path}: expected a JSON object of manifest fields, got {type(manifest).__name__}")
        for key in ("schema_version", "format", "shards", "counts", "splits", "provenance"):
            if key not in manifest:
                raise DatasetError(f"{path}: missing field {key!r}")
        if manifest["format"] != FORMAT:
            raise DatasetError(f"{path}: field 'format' is {manifest['format']!r}, expected {FORMAT!r}")
        if manifest["schema_version"] != SCHEMA_VERSION:
            raise DatasetError(
                f"{path}: field 'schema_version' is {manifest['schema_version']}; this seal reads {SCHEMA_VERSION}"
            )
        _check_totals(path, manifest)
        return cls(root, manifest)

    def __len__(self) -> int:
        return int(self.manifest["counts"]["scenarios"])

    @property
    def splits(self) -> dict[str, list[str]]:
        return self.manifest["splits"]

    def load(
        self, split: str | None = None, ids: Iterable[str] | None = None, limit: int | None = None
    ) -> list[Scenario]:
        """Load scenarios in dataset order, optionally only those of ``split`` or with the given ``ids``, and at
        most ``limit`` of them (shards past the limit are not read)."""
        wanted: set[str] | None = None
        if split is not None:
            if split not in self.splits:
                raise DatasetError(
                    f"{self.root}: no split {split!r}; available: {sorted(self.splits) or 'none (run seal data split)'}"
                )
            wanted = set(self.splits[split])
        if ids is not None:
            ids = set(ids)
            wanted = ids if wanted is None else wanted & ids
        out: list[Scenario] = []
        for entry in self.manifest["shards"]:
            if limit is not None and len(out) >= limit:
                return out[:limit]
            out.extend(self.apply_roles(s) for s in read_shard(self.root / entry["file"], entry, wanted))
        if limit is not None:
            out = out[:limit]
        if ids is not None:
            missing = set(ids) - {s.scenario_id for s in out}
            if missing:
                raise DatasetError(f"{self.root}: unknown scenario ids {sorted(missing)[:5]}")
        return out

    @property
    def roles(self) -> dict[str, list[int]]:
        """``{scenario_id: [ego_id, adv_id]}`` role assignments that override the built ones (set by
        `seal data split --hard-by pair`, which makes the higher-scoring agent of a Hard pair the ego)."""
        return self.manifest.get("roles") or {}

    def apply_roles(self, s: Scenario) -> Scenario:
        """``s`` with the manifest's role assignment for it (`roles`), if any."""
        roles = self.roles.get(s.scenario_id)
        if roles is None:
            return s
        try:
            return s.with_roles(int(roles[0]), int(roles[1]))
        except (ScenarioError, TypeError, ValueError, IndexError) as exc:
            raise DatasetError(
                f"{self.root / MANIFEST}: field 'roles' of scenario {s.scenario_id!r} is invalid ({exc}); "
                "re-run `seal data split`"
            ) from None

    def get(self, scenario_id: str) -> Scenario:
        return self.load(ids=[scenario_id])[0]

    def update_manifest(self, **fields: Any) -> None:
        """Atomically replace top-level manifest fields (e.g. ``splits``)."""
        self.manifest.update(fields)
        atomic_write_json(self.root / MANIFEST, self.manifest)


def scenario_facts(root: str | Path) -> dict[str, dict[str, str]]:
    """``{scenario_id: {"layout", "source"}}`` of every scenario of a dataset, read from the shards' id, road and
    metadata columns only (no tracks are decoded): ``layout`` as `Scenario.layout` gives it, ``source`` the
    recording file an imported scenario came from (``metadata["source_file"]``), else `Scenario.source`."""
    ds = Dataset.open(root)
    facts: dict[str, dict[str, str]] = {}
    for entry in ds.manifest["shards"]:
        try:
            with np.load(ds.root / entry["file"], allow_pickle=False) as z:
                ids, metas, roads = z["scenario_ids"], z["metadata_json"], z["roads_json"]
                road_index, sources = z["road_index"], z["sources"]
        except (KeyError, zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
            raise DatasetError(f"shard file {ds.root / entry['file']} is unreadable ({exc})") from None
        road_layouts = [str(json.loads(str(r)).get("layout", "")) for r in roads]
        for sid, meta_json, ri, source in zip(ids, metas, road_index, sources, strict=True):
            meta = json.loads(str(meta_json))
            facts[str(sid)] = {"layout": str(meta.get("layout", road_layouts[int(ri)])),
                               "source": str(meta.get("source_file") or source)}
    return facts


def load_scenarios(root: str | Path, split: str | None = None) -> list[Scenario]:
    """Shortcut for ``Dataset.open(root).load(split)``."""
    return Dataset.open(root).load(split)


ALL = "all"
"""``load_split`` name for every scenario of a dataset (as ``split=None``)."""
ALL_BUT_EVAL = "all-but-eval"
"""``load_split`` name for every scenario outside the held-out splits (`HELD_OUT_SPLITS`)."""
HELD_OUT_SPLITS = ("eval", "hard")
"""Splits that evaluation scores on, so model fits that must not see them leave them out."""


def load_split(
    root: str | Path | None, split: str | None, limit: int | None = None, what: str = "", allow_empty: bool = False
) -> list[Scenario]:
    """The scenarios of ``split`` of the dataset at ``root``, in dataset order, at most ``limit`` of them.

    ``split`` is a split name, None or `ALL` (every scenario) or `ALL_BUT_EVAL` (every scenario outside
    `HELD_OUT_SPLITS`). ``what`` names the scenarios' use in error messages (e.g. ``"training"``). Raises
    ValueError when ``root`` is None, the split does not exist, or (unless ``allow_empty``) it has no scenarios.
    """
    if root is None:
        raise ValueError(f"no dataset given for the {what or 'requested'} scenarios (--dataset DIR)")
    ds = Dataset.open(root)
    of_what = f" for the {what} scenarios" if what else ""
    params = ds.manifest.get("split_params") or {}
    if split not in (None, ALL) and params.get("method") == "safeshift" and "shared_groups" not in params:
        raise ValueError(
            f"dataset {root}: its splits were drawn before splits kept each recording / traffic run in one split "
            f"(windows of one run may be in train and eval); run `seal data score {root}` and "
            f"`seal data split {root}` again"
        )
    if split in (None, ALL):
        scenarios = ds.load(limit=limit)
    elif split == ALL_BUT_EVAL:
        held = {sid for name in HELD_OUT_SPLITS for sid in ds.splits.get(name, [])}
        if not held:
            raise ValueError(
                f"split {ALL_BUT_EVAL}: {root} has no {' / '.join(HELD_OUT_SPLITS)} split to leave out "
                f"(run `seal data split` first, or use split {ALL})"
            )
        scenarios = _outside_groups(ds.load(), held)[:limit]
    elif split not in ds.splits:
        raise ValueError(
            f"dataset {root} has no split {split!r}{of_what}; splits: {sorted(ds.splits) or 'none'} "
            f"(make them with `seal data split`; {ALL} / {ALL_BUT_EVAL} ignore splits)"
        )
    else:
        scenarios = ds.load(split=split, limit=limit)
    if not scenarios and not allow_empty:
        raise ValueError(f"dataset {root}: no{' ' + what if what else ''} scenarios in split {split!r}")
    return scenarios


def _outside_groups(scenarios: Sequence[Scenario], held: set[str]) -> list[Scenario]:
    """The scenarios that are not in ``held`` and share no recording / traffic run (`group_of`) with one that is,
    so that a fit on them never sees another window of a held-out scene. Without group ids (hand-built
    datasets) each scenario is its own group."""
    try:
        held_groups = {group_of(s) for s in scenarios if s.scenario_id in held}
        return [s for s in scenarios if s.scenario_id not in held and group_of(s) not in held_groups]
    except GroupError:
        return [s for s in scenarios if s.scenario_id not in held]


def summarize(scenarios: Sequence[Scenario]) -> dict[str, Any]:
    """Counts per layout and split, agents per scenario and valid track lengths (steps)."""
    agents = np.array([s.n_agents for s in scenarios])
    lengths = np.concatenate([s.valid.sum(axis=1) for s in scenarios]) if scenarios else np.zeros(0)

    def stats(v: np.ndarray) -> dict[str, float]:
        if v.size == 0:
            return {}
        return {
            "mean": float(v.mean()),
            "min": float(v.min()),
            "p50": float(np.median(v)),
            "max": float(v.max()),
        }

    return {
        "scenarios": len(scenarios),
        "per_layout": dict(sorted(Counter(s.layout for s in scenarios).items())),
        "agents_per_scenario": stats(agents),
        "track_length_steps": stats(lengths),
    }


# --------------------------------------------------------------------------------------------- builder
class DatasetBuilder:
    """Builds a dataset shard by shard; an interrupted build resumes where it stopped.

    ``params`` identify the build (e.g. the ``seal data generate`` arguments): resuming with other
    parameters is refused instead of mixing two builds. Shards are numbered; `done` tells which exist.
    """

    def __init__(self, root: str | Path, params: dict[str, Any], overwrite: bool = False) -> None:
        self.root = Path(root)
        self.params = json.loads(json.dumps(params))
        if (self.root / MANIFEST).exists():
            if not overwrite:
                raise DatasetError(
                    f"{self.root} already holds a finished dataset; choose another --out or pass --overwrite"
                )
            shutil.rmtree(self.root)
        state_path = self.root / BUILD_STATE
        if state_path.exists() and not overwrite:
            try:
                state = json.loads(state_path.read_text())
            except json.JSONDecodeError as exc:
                raise DatasetError(f"{state_path} is corrupt ({exc}); pass --overwrite to start over") from None
            if state.get("params") != self.params:
                raise DatasetError(
                    f"{self.root} holds an unfinished build with other parameters ({state.get('params')}); "
                    "re-run with those parameters to resume, or pass --overwrite to start over"
                )
            self.shards: dict[int, dict[str, Any]] = {int(k): v for k, v in state["shards"].items()}
        else:
            if state_path.exists():
                shutil.rmtree(self.root)
            self.shards = {}
            self.root.mkdir(parents=True, exist_ok=True)
            self._save_state()

    def _save_state(self) -> None:
        atomic_write_json(
            self.root / BUILD_STATE, {"params": self.params, "shards": {str(k): v for k, v in self.shards.items()}}
        )

    def shard_path(self, index: int) -> Path:
        return self.root / SHARD_DIR / f"shard-{index:05d}.npz"

    def is_done(self, index: int) -> bool:
        return index in self.shards

    @property
    def n_done_scenarios(self) -> int:
        return sum(v["n_scenarios"] for v in self.shards.values())

    def write_shard(self, index: int, scenarios: Sequence[Scenario], info: dict[str, Any] | None = None) -> None:
        """Write shard ``index`` (may be empty: then only the build state records it)."""
        entry: dict[str, Any] = {"n_scenarios": 0, "info": info or {}}
        if scenarios:
            entry.update(write_shard(self.shard_path(index), scenarios))
            entry["file"] = str(self.shard_path(index).relative_to(self.root))
        self.shards[index] = entry
        self._save_state()

    def finalize(
        self, n_scenarios: int | None = None, provenance: dict[str, Any] | None = None
    ) -> Dataset:
        """Write the manifest (keeping the first ``n_scenarios`` in shard order) and return the dataset."""
        entries = []
        layouts: Counter[str] = Counter()
        total = 0
        for index in sorted(self.shards):
            entry = self.shards[index]
            if entry["n_scenarios"] == 0:
                continue
            if n_scenarios is not None and total >= n_scenarios:
                self.shard_path(index).unlink(missing_ok=True)
                continue
            path = self.shard_path(index)
            scenarios = read_shard(path, entry)
            if n_scenarios is not None and total + len(scenarios) > n_scenarios:
                scenarios = scenarios[: n_scenarios - total]
                entry = {**entry, **write_shard(path, scenarios)}
            layouts.update(s.layout for s in scenarios)
            total += len(scenarios)
            entries.append({k: entry[k] for k in ("file", "n_scenarios", "bytes", "sha256")})
        if n_scenarios is not None and total < n_scenarios:
            raise DatasetError(f"{self.root}: only {total} scenarios were built, {n_scenarios} requested")
        manifest = {
            "format": FORMAT,
            "schema_version": SCHEMA_VERSION,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "provenance": {**(provenance or {}), "build_params": self.params},
            "counts": {"scenarios": total, "per_layout": dict(sorted(layouts.items()))},
            "splits": {},
            "shards": entries,
        }
        atomic_write_json(self.root / MANIFEST, manifest)
        (self.root / BUILD_STATE).unlink(missing_ok=True)
        return Dataset(self.root, manifest)


def write_dataset(
    root: str | Path, scenarios: Sequence[Scenario], provenance: dict[str, Any] | None = None,
    shard_size: int = 500, overwrite: bool = False,
) -> Dataset:
    """Write a list of scenarios as a finished dataset (used by importers and tests)."""
    builder = DatasetBuilder(root, {"writer": "write_dataset", "n": len(scenarios)}, overwrite=overwrite)
    for k, start in enumerate(range(0, len(scenarios), shard_size)):
        builder.write_shard(k, scenarios[start : start + shard_size])
    return builder.finalize(provenance=provenance)
