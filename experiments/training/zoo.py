"""rl-baselines3-zoo hyperparameter files for ``seal train --hyperparams FILE``, and the two zoo value forms seal's
configs accept: schedules (``lin_3e-4``) and ``policy_kwargs`` (a mapping, or the zoo's ``"dict(...)"`` text).

A zoo file maps an env id to the settings of one algorithm (``hyperparams/sac.yml``: ``seal/Scenario-v0: {...}``);
seal also takes it keyed by algorithm (``sac: {...}``, ``td3: {...}``). `zoo_overrides` turns the chosen entry into
``seal train`` options: ``n_timesteps`` -> ``total_timesteps``, ``n_envs`` -> ``n_envs``, ``policy_kwargs`` ->
``net_arch`` + ``policy_kwargs``, TD3's ``noise_type: normal`` / ``noise_std`` -> ``action_noise_std``, every other
key -> ``hyperparams.<algo>.<key>`` (checked against the algorithm's settings like any config key). What seal's
training cannot honour (``normalize``, env wrappers, frame stacking, callbacks, another policy than MlpPolicy) is
refused with the key named, never dropped.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from seal.core.config import ConfigError, read_yaml

ZOO_ALGOS = ("td3", "sac", "ppo")
ENV_ID = "seal/Scenario-v0"
ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Mish", "Sigmoid", "Softplus", "SELU", "CELU",
               "Hardswish", "Hardtanh", "PReLU", "Identity")
"""``torch.nn`` activations a ``policy_kwargs.activation_fn`` may name."""
UNSUPPORTED = {
    "normalize": "VecNormalize during training is not supported; drop it (or set it to false)",
    "env_wrapper": "env wrappers are not supported by seal train",
    "vec_env_wrapper": "vec-env wrappers are not supported by seal train",
    "frame_stack": "frame stacking is not supported by seal train",
    "callback": "zoo callbacks are not supported by seal train",
    "normalize_kwargs": "VecNormalize during training is not supported",
}


def parse_schedule(value: float | str, key: str) -> float | Callable[[float], float]:
    """A learning rate / clip range: a number, numeric text, or the zoo's ``lin_<start>`` (linear from ``start`` at
    the first step to 0 at the last; SB3 passes the remaining progress 1 -> 0)."""
    if not isinstance(value, str):
        return float(value)
    text = value.strip()
    try:
        if text.startswith("lin_"):
            start = float(text[4:])
            return lambda progress_remaining: progress_remaining * start
        return float(text)
    except ValueError:
        raise ConfigError(f"{key}: {value!r} is not a number or an rl-zoo schedule like lin_3e-4") from None


def check_schedule(value: float | str) -> bool:
    """True when `parse_schedule` accepts ``value`` and it starts above 0."""
    try:
        parsed = parse_schedule(value, "")
    except ConfigError:
        return False
    return (parsed(1.0) if callable(parsed) else parsed) > 0


def _node_value(node: ast.expr, text: str) -> Any:
    if isinstance(node, ast.Attribute | ast.Name):  # nn.ReLU, th.nn.Tanh, ReLU
        name = node.attr if isinstance(node, ast.Attribute) else node.id
        if name in ACTIVATIONS:
            return name
        raise ConfigError(f"policy_kwargs {text!r}: {ast.unparse(node)} is not an allowed activation "
                          f"({', '.join(ACTIVATIONS)})")
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        return {kw.arg: _node_value(kw.value, text) for kw in node.keywords if kw.arg}
    if isinstance(node, ast.Dict):
        return {ast.literal_eval(k): _node_value(v, text) for k, v in zip(node.keys, node.values, strict=True)
                if k is not None}
    if isinstance(node, ast.List | ast.Tuple):
        return [_node_value(e, text) for e in node.elts]
    try:
        return ast.literal_eval(node)
    except ValueError:
        raise ConfigError(f"policy_kwargs {text!r}: {ast.unparse(node)} is not a plain value") from None


def parse_policy_kwargs(value: str | Mapping[str, Any]) -> dict[str, Any]:
    """``policy_kwargs`` as a mapping, or the zoo's text ``"dict(net_arch=[400, 300], activation_fn=nn.ReLU)"``
    (read with ``ast``, never evaluated): plain values, activations by name."""
    if isinstance(value, Mapping):
        out = dict(value)
    else:
        try:
            tree = ast.parse(str(value).strip(), mode="eval")
        except SyntaxError:
            raise ConfigError(f"policy_kwargs {value!r}: not a dict(...) or {{...}} expression") from None
        out = _node_value(tree.body, str(value))
        if not isinstance(out, dict):
            raise ConfigError(f"policy_kwargs {value!r}: not a dict(...) or {{...}} expression")
    activation = out.get("activation_fn")
    if isinstance(activation, str):
        out["activation_fn"] = activation.rsplit(".", 1)[-1]
        if out["activation_fn"] not in ACTIVATIONS:
            raise ConfigError(f"policy_kwargs.activation_fn {activation!r}: one of {', '.join(ACTIVATIONS)}")
    return out


def _entry(data: Mapping[str, Any], algo: str | None, path: Path) -> tuple[str, Mapping[str, Any]]:
    """(algorithm, settings) of an algorithm-keyed or env-keyed zoo file."""
    keys = [str(k) for k in data]
    if keys and all(k.lower() in ZOO_ALGOS for k in keys):
        by_algo = {k.lower(): v for k, v in data.items()}
        if algo is None and len(by_algo) > 1:
            raise ConfigError(f"{path}: settings for {', '.join(sorted(by_algo))}; choose one with --algo")
        chosen = algo or next(iter(by_algo))
        if chosen not in by_algo:
            raise ConfigError(f"{path}: no settings for algo {chosen!r} (it has {', '.join(sorted(by_algo))})")
        return chosen, by_algo[chosen]
    if algo is None:
        raise ConfigError(f"{path}: an env-keyed zoo file does not say its algorithm; pass --algo td3|sac|ppo")
    env_key = ENV_ID if ENV_ID in data else (keys[0] if len(keys) == 1 else None)
    if env_key is None:
        raise ConfigError(f"{path}: entries for {', '.join(keys)}; seal reads the one named {ENV_ID!r}")
    return algo, data[env_key]


def zoo_overrides(path: str | Path, algo: str | None = None) -> dict[str, Any]:
    """``seal train`` options (dotted keys) from the zoo file ``path`` (module docstring); ``algo`` picks the entry
    of an algorithm-keyed file and is required for an env-keyed one."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"--hyperparams {path}: no such file")
    data = read_yaml(path)
    if not isinstance(data, Mapping) or not data:
        raise ConfigError(f"--hyperparams {path}: expected a mapping of env ids or algorithms to settings")
    algo, entry = _entry(data, algo.lower() if algo else None, path)
    if algo not in ZOO_ALGOS:
        raise ConfigError(f"--hyperparams {path}: algo {algo!r} is not one of {', '.join(ZOO_ALGOS)}")
    if not isinstance(entry, Mapping):
        raise ConfigError(f"--hyperparams {path}: the {algo} entry is not a mapping of settings")
    out: dict[str, Any] = {"algo": algo}
    hp = f"hyperparams.{algo}"
    for key, value in entry.items():
        where = f"{path}: {key}"
        if key in UNSUPPORTED and value not in (False, None):
            raise ConfigError(f"{where}: {UNSUPPORTED[key]}")
        if key in UNSUPPORTED:
            continue
        if key == "n_timesteps":
            out["total_timesteps"] = int(float(value))
        elif key == "n_envs":
            out["n_envs"] = int(value)
        elif key == "policy":
            if value != "MlpPolicy":
                raise ConfigError(f"{where}: seal trains MlpPolicy only (the observation is a flat vector)")
        elif key == "policy_kwargs":
            kwargs = parse_policy_kwargs(value)
            if isinstance(kwargs.get("net_arch"), list):
                out[f"{hp}.net_arch"] = kwargs.pop("net_arch")
            out[f"{hp}.policy_kwargs"] = kwargs
        elif key in ("noise_type", "noise_std") and algo == "td3":
            if key == "noise_type" and value != "normal":
                raise ConfigError(f"{where}: only normal action noise is supported, got {value!r}")
            if key == "noise_std":
                out[f"{hp}.action_noise_std"] = float(value)
        else:
            out[f"{hp}.{key}"] = value
    return out


def check_algo_settings(algo: str, keys: Mapping[str, Any] | list[str], source: str) -> None:
    """Refuse ``hyperparams.<other algorithm>.*`` settings: the run uses ``algo``'s only, so they would be
    silently ignored."""
    for key in keys:
        parts = str(key).split(".")
        if len(parts) > 1 and parts[0] == "hyperparams" and parts[1] != algo:
            raise ConfigError(f"{source} {key}: the run trains {algo}, so settings of {parts[1]} would be ignored; "
                              f"set hyperparams.{algo}.{'.'.join(parts[2:]) or '...'} instead (or --algo {parts[1]})")
