"""What the plugin groups' documentation promises a package that registers one: the types it names exist."""
from __future__ import annotations

import importlib
import re

from aril_ros import plugins


def test_every_type_the_plugin_groups_name_exists():
    """A dotted name must import; a bare CamelCase one (a type an entry point takes or returns) must be a class of
    the library or of the ROS side."""
    doc = plugins.__doc__
    dotted = set(re.findall(r"\b(aril_ros(?:_nodes)?(?:\.\w+)+)", doc)) - set(plugins.GROUPS)
    for name in sorted(dotted):
        module, _, attribute = name.rpartition(".")
        try:
            importlib.import_module(name)
        except ModuleNotFoundError:
            assert hasattr(importlib.import_module(module), attribute), name
    bare = set(re.findall(r"(?<![.\w])([A-Z][a-z]+[A-Z]\w*)", doc))
    defined = {name.rpartition(".")[2] for name in dotted}
    assert bare <= defined, f"{sorted(bare - defined)} named, not found in {sorted(dotted)}"
