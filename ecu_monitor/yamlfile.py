"""YAML text -> Python data with one rule plain ``yaml.safe_load`` lacks: a mapping that repeats a key
is refused (safe_load silently keeps the last value, so a file that sets ``c_w`` twice would run with
the value a reader did not see)."""

from __future__ import annotations

from typing import Any

import yaml

__all__ = ["DuplicateKeyError", "load_yaml_text"]


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A mapping repeats a key; the message names the key and its line (1-based)."""


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys in any mapping."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _value_node in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                repeated = key in seen
            except TypeError:  # an unhashable key: SafeLoader's own error follows
                continue
            if repeated:
                line = key_node.start_mark.line + 1
                raise DuplicateKeyError(None, None, f"{key}: duplicate key (line {line})", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def load_yaml_text(text: str) -> Any:
    """Parse YAML like ``yaml.safe_load``, refusing a mapping that repeats a key.

    Raises yaml.YAMLError (DuplicateKeyError for a repeated key) on bad text.
    """
    return yaml.load(text, Loader=_StrictLoader)
