"""YAML text -> Python data with the rules plain ``yaml.safe_load`` lacks, for every YAML file we read
(service config, model.yaml, mapping, mission, calibration):

- a mapping that repeats a key is refused (safe_load silently keeps the last value, so a file that sets
  ``c_w`` twice would run with the value a reader did not see);
- nesting deeper than :data:`MAX_DEPTH` is refused (50,000 ``[`` would otherwise end in a RecursionError);
- an integer longer than :data:`MAX_NUMBER_CHARS` characters is refused (Python itself refuses 4,300 digits);
- aliases that expand to more than :data:`MAX_NODES` values are refused (a "billion laughs" file is a few
  lines that alias a list nine times over: every later step, even an error message, would walk 10^9 items).
"""

from __future__ import annotations

import os
from typing import Any

import yaml

from ecu_monitor.errors import UserInputError
from ecu_monitor.userfiles import read_input_text

__all__ = [
    "MAX_DEPTH",
    "MAX_NODES",
    "MAX_NUMBER_CHARS",
    "DuplicateKeyError",
    "YamlLimitError",
    "load_yaml_file",
    "load_yaml_text",
    "yaml_problem",
]

#: Deepest nesting of lists and mappings accepted (our files nest four or five levels).
MAX_DEPTH = 64
#: Most values one document may hold once its aliases are expanded (a large heat map holds a few hundred).
MAX_NODES = 100_000
#: Longest integer accepted, in characters.
MAX_NUMBER_CHARS = 100


class DuplicateKeyError(yaml.constructor.ConstructorError):
    """A mapping repeats a key; the message names the key and its line (1-based)."""


class YamlLimitError(yaml.composer.ComposerError):
    """The document nests too deep or its aliases expand to too many values."""


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys, deep nesting and alias bombs."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        if self._depth > MAX_DEPTH:
            mark = self.peek_event().start_mark
            raise YamlLimitError(None, None, f"nested more than {MAX_DEPTH} levels deep", mark)
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if not hasattr(node, "expanded_size"):  # a new node (an alias returns a node already sized)
            if isinstance(node, yaml.SequenceNode):
                children = node.value
            elif isinstance(node, yaml.MappingNode):
                children = [child for pair in node.value for child in pair]
            else:
                children = []
            node.expanded_size = 1 + sum(child.expanded_size for child in children)
            if node.expanded_size > MAX_NODES:
                raise YamlLimitError(None, None, f"aliases expand to more than {MAX_NODES} values", node.start_mark)
        return node

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        """An integer of at most :data:`MAX_NUMBER_CHARS` characters (Python refuses to read one of
        4,300 digits with a ValueError no YAML error handler expects)."""
        if len(node.value) > MAX_NUMBER_CHARS:
            message = f"a number of {len(node.value)} characters (at most {MAX_NUMBER_CHARS})"
            raise YamlLimitError(None, None, message, node.start_mark)
        return int(super().construct_yaml_int(node))

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # ``<<: *defaults``: SafeLoader merges it below
                continue
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


_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_yaml_int)


def load_yaml_text(text: str) -> Any:
    """Parse YAML like ``yaml.safe_load``, with the rules of this module.

    Raises yaml.YAMLError (DuplicateKeyError, YamlLimitError) on bad text.
    """
    return yaml.load(text, Loader=_StrictLoader)


def yaml_problem(exc: yaml.YAMLError) -> str:
    """One line for a YAML error: the problem and its line (1-based) where known."""
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}" if mark is not None else ""
    problem = getattr(exc, "problem", None) or (str(exc).splitlines() or ["?"])[0]
    return f"not valid YAML{where}: {problem}"


def load_yaml_file(path: str | os.PathLike[str], what: str, error: type[UserInputError] = UserInputError) -> Any:
    """Read YAML file ``path`` (a regular file of text; ``what`` names the kind, e.g. "model file") with
    the rules of this module; any problem raises ``error`` in one line naming the file."""
    text = read_input_text(path, what, error)
    try:
        return load_yaml_text(text)
    except yaml.YAMLError as exc:
        raise error(f"{os.fspath(path)}: {yaml_problem(exc)}") from None
