"""Stage confs: named presets plus `key=value` overrides, stored resolved in artifacts."""

from __future__ import annotations

import copy
import importlib

import yaml

from .errors import FieldlocError


def parse_overrides(items) -> dict:
    """['a=1', 'b.c=x'] -> {'a': 1, 'b': {'c': 'x'}} (values parsed as YAML scalars)."""
    out: dict = {}
    for item in items or ():
        if "=" not in item:
            raise FieldlocError(f"conf override '{item}' is not of the form key=value")
        key, value = item.split("=", 1)
        try:
            parsed = yaml.safe_load(value)
        except yaml.YAMLError:
            parsed = value
        d = out
        parts = key.strip().split(".")
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = parsed
    return out


def resolve_conf(confs: dict, preset: str | dict | None, overrides: dict | None = None,
                 default: str = "default") -> dict:
    """A copy of ``confs[preset]`` (or a given dict) with ``overrides`` merged in. Unknown
    preset names and unknown override keys are user errors."""
    if isinstance(preset, dict):
        base = copy.deepcopy(preset)
    else:
        name = preset or default
        if name not in confs:
            raise FieldlocError(f"unknown preset '{name}' (presets: {', '.join(sorted(confs))})")
        base = copy.deepcopy(confs[name])
    for key, value in (overrides or {}).items():
        _merge(base, key, value, key)
    return base


def stage_conf(confs: dict, conf: str | dict | None, default: str = "default") -> dict:
    """The stage contract's conf: a preset name, None (the default preset), or a dict of
    overrides on the default preset (a complete conf is a dict of overrides too); unknown
    preset names and keys are user errors."""
    if conf is None or isinstance(conf, str):
        return resolve_conf(confs, conf, default=default)
    if not isinstance(conf, dict):
        raise FieldlocError(f"a conf is a preset name or a dict of values, not {conf!r}")
    return resolve_conf(confs, default, conf, default=default)


def _merge(base: dict, key, value, path):
    if key not in base:
        raise FieldlocError(f"unknown conf key '{path}' (known: {', '.join(sorted(base))})")
    if isinstance(base[key], dict) and isinstance(value, dict):
        for k, v in value.items():
            _merge(base[key], k, v, f"{path}.{k}")
    else:
        base[key] = value


def registered_module(registry: dict[str, str], name: str, what: str):
    """The module registered under ``name`` (imported on first use); an unknown name is a user
    error that lists the known ones. ``what`` names the registry in the message."""
    if name not in registry:
        raise FieldlocError(f"unknown {what} '{name}' (known: {', '.join(registry)})")
    return importlib.import_module(registry[name])
