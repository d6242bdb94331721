"""Frozen config dataclasses ↔ JSON dicts, exactly, and the differences between two.

Every configuration in collavn (``EnvConfig``, ``ModelConfig``, ``TrainConfig``, …) is a
frozen dataclass tree. :func:`to_dict` turns one into JSON-compatible values (tuples
become lists); :func:`from_dict` rebuilds it and refuses a dict with an unknown or a
missing key, naming the dotted path, so a saved ``config.json`` round-trips exactly or
not at all. The one exception is a field declared with :func:`added_later`: a key added
after files were written whose default is the behaviour before it existed, so an older
file lacking it still loads (as it ran).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import textwrap
import typing
from collections.abc import Sequence
from typing import Any, TypeVar

from collavn.errors import ConfigError

T = TypeVar("T")


#: Field metadata key of :func:`added_later`.
_ADDED_LATER = "collavn_added_later"


def added_later(default: Any) -> Any:
    """A field added after files were written, ``default`` being the behaviour before it.

    :func:`from_dict` fills it in when a file written earlier lacks the key.
    """
    return dataclasses.field(default=default, metadata={_ADDED_LATER: True})


def to_dict(config: Any) -> dict[str, Any]:
    """JSON-compatible dict of a dataclass tree (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def from_dict(cls: type[T], data: dict[str, Any], path: str = "") -> T:
    """Rebuild ``cls`` from :func:`to_dict` output.

    Raises:
        ConfigError: ``data`` is not a dict, has a key ``cls`` does not know, or lacks
            one it needs (the message names the dotted path), or a value is refused by
            the dataclass's own checks.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"config {path or cls.__name__}: expected a mapping, got "
                          f"{type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"unknown config key {path}{unknown[0]!s} (known: "
                          f"{', '.join(sorted(fields))})")
    missing = sorted(name for name in set(fields) - set(data)
                     if not fields[name].metadata.get(_ADDED_LATER))
    if missing:
        raise ConfigError(f"config is missing key {path}{missing[0]} (written by another "
                          f"version of collavn?)")
    hints = typing.get_type_hints(cls)
    values = {name: _value(hints[name], data[name], f"{path}{name}.") for name in fields
              if name in data}
    try:
        return cls(**values)
    except ConfigError:
        raise
    except (TypeError, ValueError) as e:
        raise ConfigError(f"config {path or cls.__name__}: {e}") from e


def _value(hint: Any, value: Any, path: str) -> Any:
    """Rebuild one field: nested dataclasses recurse, lists become tuples."""
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return from_dict(hint, value, path)
    if typing.get_origin(hint) is tuple and isinstance(value, list):
        return tuple(value)
    return value


def differences(a: Any, b: Any, prefix: str = "") -> dict[str, tuple[Any, Any]]:
    """``{"dotted.path": (a value, b value)}`` for every leaf where two dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out: dict[str, tuple[Any, Any]] = {}
        for k in sorted(set(a) | set(b)):
            out.update(differences(a.get(k), b.get(k), f"{prefix}{k}."))
        return out
    return {} if a == b else {prefix[:-1]: (a, b)}


def check_count(name: str, value: int, minimum: int = 1) -> None:
    """Refuse an integer ``value`` below ``minimum`` (a count, a size, an interval).

    Raises:
        ConfigError: naming the option (``name``, e.g. ``--num-envs``) and the value.
    """
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{name} must be an integer ≥ {minimum}, got {value!r}")


def check_number(name: str, value: float, minimum: float = 0.0, *,
                 allow_minimum: bool = False) -> None:
    """Refuse a NaN, infinite, or too small number (``> minimum``, or ``≥`` if allowed).

    Raises:
        ConfigError: naming the option and the value.
    """
    ok = (isinstance(value, int | float) and not isinstance(value, bool)
          and math.isfinite(value)
          and (value >= minimum if allow_minimum else value > minimum))
    if not ok:
        bound = f"≥ {minimum:g}" if allow_minimum else f"> {minimum:g}"
        raise ConfigError(f"{name} must be a finite number {bound}, got {value!r}")


_LIST_ITEM = re.compile(r"^([-*•]|\d+[.)])\s")


def join_docstring_lines(text: str) -> str:
    """A docstring as help text: source line breaks joined, paragraphs and list items kept.

    An attribute docstring's continuation lines carry the class body's indentation; the
    first line does not. Lines are dedented after the first, then each line is joined to
    the one before it with a space unless it is blank (a paragraph break, kept as one
    blank line) or starts a list item (``-``, ``*``, ``•``, ``1.``, ``1)``).
    """
    first, _, rest = text.partition("\n")
    lines = [first.strip(), *textwrap.dedent(rest).splitlines()] if rest else [first.strip()]
    out: list[str] = []
    for line in (ln.rstrip() for ln in lines):
        if not line:
            if out and out[-1] != "":
                out.append("")
        elif out and out[-1] != "" and not _LIST_ITEM.match(line.lstrip()):
            out[-1] += " " + line.strip()
        else:
            out.append(line)
    return "\n".join(out).strip("\n")


def use_tyro() -> Any:
    """The ``tyro`` module, set to join a docstring's source line breaks in ``--help``.

    tyro (1.0.x) joins single line breaks before it removes the class body's indentation,
    so every continuation line of an attribute docstring starts with a space and keeps its
    break, and the help wraps at the source's line ends. Its private joiner is replaced by
    :func:`join_docstring_lines`; on a tyro without it, help is left as tyro makes it.
    """
    import tyro

    strings = getattr(tyro, "_strings", None)
    if strings is not None and hasattr(strings, "remove_single_line_breaks"):
        strings.remove_single_line_breaks = join_docstring_lines
    return tyro


def parse_with_presets(presets: dict[str, tuple[str, T]], args: Sequence[str], prog: str,
                       purpose: str, default: str) -> T:
    """``[--preset NAME] [flags]`` → the preset ``NAME`` (else ``default``) with flags applied.

    Every field of the config is a flag; the preset supplies the defaults through
    tyro's overridable configs (``--preset cpu`` is the subcommand ``cpu``).

    Raises:
        ConfigError: an unknown preset name.
    """
    tyro = use_tyro()
    rest, preset = list(args), default
    for i, a in enumerate(rest):
        if a == "--preset" and i + 1 < len(rest):
            preset = rest[i + 1]
            del rest[i:i + 2]
            break
        if a.startswith("--preset="):
            preset = a.split("=", 1)[1]
            del rest[i]
            break
    if preset not in presets:
        raise ConfigError(f"unknown preset {preset!r}; expected one of {', '.join(presets)}")
    description = (f"{purpose}; preset {preset!r}: {presets[preset][0]} Choose the preset "
                   f"with --preset {{{','.join(presets)}}} (default {default}).")
    return tyro.extras.overridable_config_cli(
        {preset: (description, presets[preset][1])}, args=[preset, *rest], prog=prog,
        description=description)
