"""Reading a config file: safe YAML (no duplicate keys), ``--set`` overrides, validation errors that name the key."""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from cellctl.config.cell import CellConfig
from cellctl.config.files import PROJECT_ROOT, default_config_path
from cellctl.errors import ConfigError


class _Loader(yaml.SafeLoader):
    """safe_load, but only true/false are booleans (``on``/``off``/``yes``/``no`` stay strings)."""


_Loader.yaml_implicit_resolvers = {
    k: [(tag, rx) for tag, rx in v if tag != "tag:yaml.org,2002:bool"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
for _first in "tTfF":
    _Loader.add_implicit_resolver(
        "tag:yaml.org,2002:bool",
        __import__("re").compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
        list(_first),
    )


class _DuplicateKey(yaml.YAMLError):
    """A mapping names one key twice: YAML lets the last one win silently, we refuse it."""


def _mapping_without_duplicates(loader: _Loader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    first: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            line = first.setdefault(key, key_node.start_mark.line)
        except TypeError:  # an unhashable key: construct_mapping says so
            continue
        if line != key_node.start_mark.line:
            raise _DuplicateKey(
                f"duplicate key {key!r} at line {key_node.start_mark.line + 1} (first at line {line + 1}); "
                "give each key once"
            )
    return loader.construct_mapping(node, deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_without_duplicates)


def safe_yaml_load(text: str, source: str = "<string>") -> Any:
    """Parse YAML safely; raise ConfigError with the location on syntax errors."""
    try:
        return yaml.load(text, Loader=_Loader)  # _Loader derives from SafeLoader
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: not valid YAML: {err}") from err


def _allowed_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str] | None:
    """Field names of the model that holds the key at ``loc`` (for 'unknown key' messages)."""
    current: Any = model
    for part in loc[:-1]:
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            return None
        field = current.model_fields.get(str(part))
        if field is None:
            return None
        current = field.annotation
        for arg in typing.get_args(current) or ():
            if isinstance(arg, type) and issubclass(arg, BaseModel):
                current = arg
    if isinstance(current, type) and issubclass(current, BaseModel):
        return sorted(k for k in current.model_fields if k != "root")
    return None


def explain_validation(err: ValidationError, model: type[BaseModel], source: str) -> str:
    """One line per problem: key path, what is wrong, the value given, what is allowed."""
    lines = []
    for e in err.errors():
        loc = tuple(e["loc"])
        key = ".".join(str(x) for x in loc) or "(top level)"
        if e["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, loc)
            lines.append(f"{source}: unknown key {key!r}; allowed keys here: {allowed}")
        else:
            given = e.get("input")
            shown = repr(given)
            if len(shown) > 80:
                shown = shown[:77] + "..."
            lines.append(f"{source}: key {key!r}: {e['msg']} (got {shown})")
    return "\n".join(lines)


def _set_dotted(data: dict[str, Any], dotted: str, raw_value: str) -> None:
    if "=" in dotted and raw_value == "":
        dotted, raw_value = dotted.split("=", 1)
    parts = dotted.split(".")
    node = data
    for p in parts[:-1]:
        nxt = node.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"--set {dotted}: {p!r} is not a section")
        node = nxt
    node[parts[-1]] = safe_yaml_load(raw_value, f"--set {dotted}")


def apply_overrides(data: dict[str, Any], overrides: list[str] | None, flag: str = "--set") -> None:
    """Apply ``key.path=value`` strings (values parsed as YAML) to a parsed config mapping.

    Raises:
        ConfigError: an override has no ``=`` or names a key below a non-section.
    """
    for ov in overrides or []:
        if "=" not in ov:
            raise ConfigError(f"{flag} {ov!r}: expected KEY.PATH=VALUE")
        k, v = ov.split("=", 1)
        _set_dotted(data, k.strip(), v)


def load_config(path: Path | str | None = None, overrides: list[str] | None = None) -> CellConfig:
    """Load and validate a cell config.

    Args:
        path: YAML file; ``None`` means the default ``config/cell.yaml``.
        overrides: ``key.path=value`` strings applied after the file (``--set``).

    Raises:
        ConfigError: the file is missing, not YAML, or does not validate; the message names
            every offending key, its value and what is allowed.
    """
    p = Path(path) if path is not None else default_config_path()
    if not p.is_file():
        raise ConfigError(f"config file {str(p)!r} does not exist")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{p}: not a YAML text file (byte {err.start} is not UTF-8 text)") from None
    data = safe_yaml_load(text, str(p))
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: top level must be a mapping of sections, got {type(data).__name__}")
    apply_overrides(data, overrides)
    root = p.resolve().parent
    if root.name == "config":
        root = root.parent
    try:
        cfg = CellConfig.model_validate({**data, "root": root})
    except ValidationError as err:
        raise ConfigError(explain_validation(err, CellConfig, str(p))) from err
    # a cell folder outside the install names what it has; what it does not name is the install's
    if "catalog" not in data and not cfg.path(cfg.catalog).exists():
        cfg.catalog = PROJECT_ROOT / cfg.catalog
    if "models_dir" not in (data.get("classifier") or {}) and not cfg.path(cfg.classifier.models_dir).exists():
        cfg.classifier.models_dir = PROJECT_ROOT / cfg.classifier.models_dir
    return cfg
