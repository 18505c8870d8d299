"""Path prefixes inside recorded values: what a folder's records say when the folder moves.

Run folders record absolute paths (a training run's dataset and models, the results store's run and dataset keys).
When the folder is moved or copied, `rebase` points the paths that lie inside its old location at the new one and
leaves every other value as it is; `portable_json` writes a value with the folder's path as a placeholder, so a hash
of it does not depend on where the folder is.
"""

from __future__ import annotations

import json
import re
from typing import Any

FOLDER_PLACEHOLDER = "${OUT}"
"""What `portable_json` writes in place of the folder's path."""


def rebase(value: str, old: str, new: str) -> str:
    """``value`` with the leading folder ``old`` replaced by ``new`` when it is ``old`` itself or a path below it
    (``old/...``); any other string unchanged (``old2/x`` is not below ``old``)."""
    if value == old:
        return new
    if value.startswith(old.rstrip("/") + "/"):
        return new.rstrip("/") + value[len(old.rstrip("/")):]
    return value


def rebase_tree(value: Any, old: str, new: str) -> Any:
    """`rebase` applied to every string in nested dicts / lists / tuples (keys unchanged); a new object."""
    if isinstance(value, str):
        return rebase(value, old, new)
    if isinstance(value, dict):
        return {k: rebase_tree(v, old, new) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(rebase_tree(v, old, new) for v in value)
    return value


def portable_json(value: Any, folder: str, as_folder: str = FOLDER_PLACEHOLDER) -> str:
    """``json.dumps(value, sort_keys=True, default=str)`` with ``folder`` written as ``as_folder`` wherever a string
    is ``folder`` or starts with ``folder/`` (a prefix of a longer name, ``folder2``, is kept)."""
    return swap_folder(json.dumps(value, sort_keys=True, default=str), folder, as_folder)


def swap_folder(text: str, folder: str, as_folder: str = FOLDER_PLACEHOLDER) -> str:
    """JSON ``text`` with ``folder`` written as ``as_folder`` in its strings, as `portable_json` does."""
    escaped = json.dumps(folder.rstrip("/"))[1:-1]  # as the folder appears inside a JSON string
    target = json.dumps(as_folder)[1:-1].replace("\\", "\\\\")
    # Inside a JSON string the folder is followed by "/" (a path below it) or by the string's closing quote.
    return re.sub('(?<=")' + re.escape(escaped) + '(?=[/"])', target, text)
