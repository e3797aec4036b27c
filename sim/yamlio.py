"""YAML configuration loading that remembers where every value came from.

Configuration is validated at the edge: a file is read into plain dicts and lists that also carry
the line of each key, and a :class:`Section` reads typed fields out of a mapping, so that a bad
value fails with the file, the line and the field, e.g.::

    configs/vehicles/bad.yaml:3: mass: must be > 0 (got -1.0)

:class:`ConfigError` is the one exception type for bad configuration across the project.
"""

from __future__ import annotations

import difflib
import math
import re
from pathlib import Path
from typing import Any, Iterable, NoReturn

import numpy as np
import yaml

__all__ = ["ConfigError", "YamlMap", "YamlList", "load_yaml", "Section", "REQUIRED", "described",
           "closest", "did_you_mean", "choose"]


class ConfigError(ValueError):
    """A configuration file or mapping is malformed or physically impossible."""


class YamlMap(dict):
    """A dict loaded from YAML; ``lines[key]`` is the 1-based line of each key.

    ``origins[key]``, when set, names the section a key was written in if that is not the
    mapping's own (an experiment's ``defaults`` merged into each scenario): errors about the key
    name that section."""

    def __init__(self, *args, line: int | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.line = line
        self.lines: dict[Any, int] = {}
        self.origins: dict[Any, str] = {}


class YamlList(list):
    """A list loaded from YAML; ``lines[i]`` is the 1-based line of item i."""

    def __init__(self, *args, line: int | None = None):
        super().__init__(*args)
        self.line = line
        self.lines: list[int] = []


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e-5`` (no dot) as a float, as YAML 1.2 and humans do."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _build(node: yaml.Node, constructor: _Loader, source: str) -> Any:
    line = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        out = YamlMap(line=line)
        merged = YamlMap(line=line)  # ``<<: *anchor`` entries: the mapping's own keys win
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                sources = value_node.value if isinstance(value_node, yaml.SequenceNode) \
                    else [value_node]
                for src in sources:
                    if not isinstance(src, yaml.MappingNode):
                        raise ConfigError(f"{source}:{key_node.start_mark.line + 1}: <<: "
                                          "merges mappings only")
                    built = _build(src, constructor, source)
                    for k, v in built.items():
                        if k not in merged:
                            merged[k] = v
                            merged.lines[k] = built.lines[k]
                continue
            key = constructor.construct_object(key_node, deep=True)
            key_line = key_node.start_mark.line + 1
            if not isinstance(key, (str, int, float, bool)) or key is None:
                raise ConfigError(f"{source}:{key_line}: keys must be scalars")
            if key in out:
                raise ConfigError(f"{source}:{key_line}: {key}: duplicate key "
                                  f"(first on line {out.lines[key]})")
            out[key] = _build(value_node, constructor, source)
            out.lines[key] = key_line
        for k, v in merged.items():
            if k not in out:
                out[k] = v
                out.lines[k] = merged.lines[k]
        return out
    if isinstance(node, yaml.SequenceNode):
        out_list = YamlList(line=line)
        for item in node.value:
            out_list.append(_build(item, constructor, source))
            out_list.lines.append(item.start_mark.line + 1)
        return out_list
    return constructor.construct_object(node, deep=True)


def load_yaml(path: str | Path, *, text: str | None = None) -> Any:
    """Read a YAML file (or ``text`` attributed to ``path``) into YamlMap / YamlList / scalars.

    An empty document loads as an empty YamlMap. Syntax errors become ConfigError with the line.
    """
    source = str(path)
    if text is None:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"{source}: cannot read: {exc.strerror or exc}") from exc
    constructor = _Loader("")
    try:
        node = yaml.compose(text, Loader=_Loader)
        if node is None:
            return YamlMap(line=1)
        return _build(node, constructor, source)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"{source}:{mark.line + 1}" if mark is not None else source
        raise ConfigError(f"{where}: invalid YAML: {exc.problem or exc.context}") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: invalid YAML: {exc}") from exc


def described(value: Any) -> str:
    """What a YAML value is, in words: 'a list', 'a mapping', "the text 'abc'", 'nothing'."""
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if value is None:
        return "nothing"
    if isinstance(value, str):
        return f"the text {value!r}"
    return repr(value)


def _folded(word: str) -> str:
    # look-alike spellings compare equal: case, a zero for an o, a one for an l, - for _
    return word.lower().replace("0", "o").replace("1", "l").replace("-", "_")


def closest(word: Any, choices: Iterable[Any]) -> str | None:
    """The choice closest to a misspelt ``word`` (difflib's ratio on look-alike-folded
    spellings), or None when none is close."""
    choices = [str(c) for c in choices]
    folded = {}
    for c in choices:
        folded.setdefault(_folded(c), c)
    close = difflib.get_close_matches(_folded(str(word)), list(folded), n=1, cutoff=0.6)
    return folded[close[0]] if close else None


def choose(value: str, choices: Iterable[str]) -> str | None:
    """The choice ``value`` names, matched regardless of case (None if none)."""
    choices = list(choices)
    if value in choices:
        return value
    same = [c for c in choices if c.lower() == value.lower()]
    return same[0] if len(same) == 1 else None


def did_you_mean(word: Any, choices: Iterable[Any]) -> str:
    """``"; did you mean 'wo'?"`` for a misspelt ``word``, or "" when no choice is close."""
    near = closest(word, choices)
    return f"; did you mean {near!r}?" if near is not None and near != word else ""


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


class Section:
    """Typed, line-aware reader of one mapping of a configuration.

    Every getter marks its key as used; :meth:`finish` rejects keys nobody asked for, so a
    misspelt option fails instead of being silently ignored. Errors read
    ``SOURCE:LINE: PATH.FIELD: reason``. Works on plain dicts too (then without line numbers).
    """

    def __init__(self, data: Any, source: str = "<mapping>", path: str = "",
                 line: int | None = None):
        self.source = str(source)
        self.path = path
        self._line = getattr(data, "line", None) or line
        if not isinstance(data, dict):
            self.error(None, f"must be a mapping (got {described(data)})")
        self.data = data
        self._used: set = set()
        self._known: set = set()  # every key asked about: the section's valid keys

    # -- reporting ---------------------------------------------------------------------------
    def line(self, key: Any = None) -> int | None:
        lines = getattr(self.data, "lines", None) if hasattr(self, "data") else None
        if key is not None and lines and key in lines:
            return lines[key]
        return self._line

    def field_name(self, key: Any) -> str:
        if key is None:
            return self.path or "(top level)"
        origins = getattr(self.data, "origins", None) if hasattr(self, "data") else None
        path = origins[key] if origins and key in origins else self.path
        return f"{path}.{key}" if path else str(key)

    def error(self, key: Any, reason: str) -> NoReturn:
        """Raise a ConfigError about ``key`` (None: the mapping itself)."""
        line = self.line(key)
        where = f"{self.source}:{line}" if line is not None else self.source
        raise ConfigError(f"{where}: {self.field_name(key)}: {reason}")

    # -- access ------------------------------------------------------------------------------
    def has(self, key: str) -> bool:
        """Whether ``key`` is given; it is one of the section's valid keys either way."""
        self._known.add(key)
        return key in self.data

    def allow(self, *keys: str) -> None:
        """Count ``keys`` among the valid keys named when an unknown one is refused (keys read
        from this mapping elsewhere)."""
        self._known.update(keys)

    def raw(self, key: str, default: Any = REQUIRED) -> Any:
        self._used.add(key)
        self._known.add(key)
        if key not in self.data:
            if default is REQUIRED:
                # a key nobody asked for that is spelt like it: the line to look at
                near = closest(key, [k for k in self.data if k not in self._known])
                line = self._line if near is None else self.line(near)
                where = f"{self.source}:{line}" if line is not None else self.source
                hint = "" if near is None else f"; is {near!r} a misspelling of it?"
                raise ConfigError(f"{where}: {self.field_name(key)}: required field "
                                  f"missing{hint}")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = REQUIRED, *, gt: float | None = None,
               ge: float | None = None, lt: float | None = None,
               le: float | None = None) -> float:
        """A finite real number, optionally bounded."""
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        if not _is_number(value):
            self.error(key, f"must be a number (got {value!r})")
        value = float(value)
        self._check_bounds(key, value, gt, ge, lt, le)
        return value

    def _check_bounds(self, key: str, value: float, gt, ge, lt, le, what: str = "") -> None:
        if not math.isfinite(value):
            self.error(key, f"{what}must be finite (got {value})")
        if gt is not None and not value > gt:
            self.error(key, f"{what}must be > {gt:g} (got {value!r})")
        if ge is not None and not value >= ge:
            self.error(key, f"{what}must be >= {ge:g} (got {value!r})")
        if lt is not None and not value < lt:
            self.error(key, f"{what}must be < {lt:g} (got {value!r})")
        if le is not None and not value <= le:
            self.error(key, f"{what}must be <= {le:g} (got {value!r})")

    def vector(self, key: str, n: int, default: Any = REQUIRED, *, scalar_ok: bool = False,
               gt: float | None = None, ge: float | None = None) -> np.ndarray:
        """A list of ``n`` numbers (or, with ``scalar_ok``, one number used for all n)."""
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value if value is None else np.array(value, dtype=float)
        if scalar_ok and _is_number(value):
            value = [value] * n
        if not isinstance(value, (list, tuple)) or len(value) != n:
            kind = f"a list of {n} numbers" + (" or one number" if scalar_ok else "")
            self.error(key, f"must be {kind} (got {value!r})")
        for i, item in enumerate(value):
            if not _is_number(item):
                self.error(key, f"item {i} must be a number (got {item!r})")
            self._check_bounds(key, float(item), gt, ge, None, None, what=f"item {i} ")
        return np.array(value, dtype=float)

    def string(self, key: str, default: Any = REQUIRED,
               choices: Iterable[str] | None = None) -> str:
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        if not isinstance(value, str):
            self.error(key, f"must be a string (got {value!r})")
        if choices is not None:
            choices = list(choices)
            chosen = choose(value, choices)
            if chosen is None:
                self.error(key, f"must be one of {', '.join(choices)} "
                                f"(got {value!r}{did_you_mean(value, choices)})")
            return chosen
        return value

    def boolean(self, key: str, default: Any = REQUIRED) -> bool:
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        if not isinstance(value, bool):
            self.error(key, f"must be true or false (got {value!r})")
        return value

    def section(self, key: str) -> "Section":
        """The nested mapping under ``key`` as a Section."""
        value = self.raw(key)
        if not isinstance(value, dict):
            self.error(key, f"must be a mapping (got {described(value)})")
        return Section(value, self.source, self.field_name(key), line=self.line(key))

    def sections(self, key: str, default: Any = REQUIRED) -> list["Section"]:
        """The list of mappings under ``key``, each as a Section named ``key[i]``."""
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        if not isinstance(value, list):
            self.error(key, f"must be a list (got {described(value)})")
        lines = getattr(value, "lines", None)
        out = []
        for i, item in enumerate(value):
            line = lines[i] if lines else self.line(key)
            name = f"{self.field_name(key)}[{i}]"
            if not isinstance(item, dict):
                where = f"{self.source}:{line}" if line is not None else self.source
                raise ConfigError(f"{where}: {name}: must be a mapping (got {described(item)})")
            out.append(Section(item, self.source, name, line=line))
        return out

    def check(self, key: str, ok: bool, reason: str) -> None:
        """Fail with ``reason`` about ``key`` unless ``ok``."""
        if not ok:
            self.error(key, reason)

    def finish(self) -> None:
        """Reject keys that no getter asked for."""
        unknown = [k for k in self.data if k not in self._used]
        if unknown:
            key = unknown[0]
            known = sorted(str(k) for k in self._known)
            self.error(key, f"unknown key{did_you_mean(key, known)} "
                            f"(valid keys here: {', '.join(known)})")



CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


def config_path(name_or_path: str | Path, folder: str) -> Path:
    """Resolve a bare name (``crazyflie``) to ``configs/FOLDER/NAME.yaml``; paths pass through.

    A value is a path if it is a Path, contains a path separator or ends in .yaml / .yml.
    """
    if isinstance(name_or_path, Path):
        return name_or_path
    text = str(name_or_path)
    if "/" in text or "\\" in text or text.endswith((".yaml", ".yml")):
        path = Path(text)
        if not path.exists():
            raise ConfigError(f"{text}: no such file{_nearest_file(path, folder)}")
        return path
    path = CONFIG_DIR / folder / f"{text}.yaml"
    if not path.exists():
        shipped = _shipped(folder)
        raise ConfigError(f"{text}: no such {folder} config (shipped: {', '.join(shipped)}"
                          f"{did_you_mean(text, shipped)})")
    return path


def _nearest_file(path: Path, folder: str) -> str:
    """"; did you mean 'X'?" for a config file that does not exist: the same name with the other
    suffix (.yml for .yaml), the shipped config of that name, or a close name beside it."""
    stem = path.name.rsplit(".", 1)[0] if path.suffix in (".yaml", ".yml") else path.name
    for candidate in (path.with_name(stem + ".yaml"), path.with_name(stem + ".yml"),
                      CONFIG_DIR / folder / f"{stem}.yaml"):
        if candidate != path and candidate.exists():
            return f"; did you mean {_shown(candidate)!r}?"
    here = path.parent if path.parent.is_dir() else None
    names = [p.name for p in here.glob("*.y*ml")] if here is not None else []
    near = closest(path.name, names)
    if near is not None:
        return f"; did you mean {str(path.with_name(near))!r}?"
    return did_you_mean(stem, _shipped(folder))


def _shipped(folder: str) -> list[str]:
    """The names of the configs shipped in ``configs/FOLDER``."""
    return sorted(p.stem for p in (CONFIG_DIR / folder).glob("*.yaml"))


def _shown(path: Path) -> str:
    """``path`` as the user would type it: relative to the working folder when under it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)
