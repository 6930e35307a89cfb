"""What the runners share on their command lines: flags as config overrides, a refused setting named by its flag."""
from __future__ import annotations

import argparse
import sys
from typing import Any

from sagp_batched.config import Config, ConfigError, load_config
from sagp_batched.config.profiles import read_profile

# A runner's flag table: flag -> (argparse dest, config section, config key).
SettingFlags = dict[str, tuple[str, str, str]]


def config_from_flags(args: argparse.Namespace, setting_flags: SettingFlags) -> Config:
    """``args.profile`` with every flag given in ``args`` laid over it; raises ``ConfigError``."""
    overrides: dict[str, dict[str, Any]] = {}
    for dest, section, key in setting_flags.values():
        overrides.setdefault(section, {})[key] = getattr(args, dest)
    return load_config(args.profile, overrides=overrides)


def setting_error(exc: ConfigError, args: argparse.Namespace, setting_flags: SettingFlags) -> str:
    """The error line of a refused setting, naming the flag when a flag gave it its value."""
    for flag, (dest, section, key) in setting_flags.items():
        if exc.setting == f"{section}.{key}" and getattr(args, dest) is not None:
            return f"error: {flag}: {exc}"
    return f"error: {exc}"


def config_or_report(args: argparse.Namespace, setting_flags: SettingFlags) -> Config | None:
    """``config_from_flags``, or None once a refused setting has been printed as one ``error:`` line."""
    try:
        return config_from_flags(args, setting_flags)
    except ConfigError as exc:
        print(setting_error(exc, args, setting_flags), file=sys.stderr)
        return None


def names_and_unknown(text: str, known: tuple[str, ...]) -> tuple[list[str], list[str]]:
    """The names of the comma list ``text``, and those of them not in ``known``."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    return names, [name for name in names if name not in known]


def workers_line(args: argparse.Namespace, config: Config) -> str:
    """The run's first word on its workers: how many, and whether ``--workers``, the profile or the cores
    available to this process (the default: ``sagp_batched.config.run.available_cores``) chose them."""
    if getattr(args, "workers", None) is not None:
        why = "--workers"
    elif "workers" in read_profile(args.profile)[1].get("run", {}):
        why = f"[run] workers of profile {args.profile}; --workers N to change"
    else:
        why = "the cores available; --workers N to change"
    return f"workers: {config.run.workers} ({why})"
