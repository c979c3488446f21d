"""The package layers do not leak: ``seagul_envs`` (tasks, envs) is the bottom, ``seagul_control`` (NLP, MPC, LQR,
evaluation) sits on it, ``seagul_learn`` (torch, training, the CLI) on both.

Every module of a lower layer is imported in a fresh interpreter in which the upper layers (and torch) cannot be
imported (``sys.modules[name] = None`` makes ``import name`` raise ``ImportError``), so an import of an upper layer at
module level anywhere fails the test, however indirect. The sources are also read: a lower layer names an upper one
only as a string (a module path resolved on use, such as a policy kind's builder), never in an import statement.
"""

from __future__ import annotations

import ast
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import seagul_control
import seagul_envs

LOWER = {"seagul_envs": ("seagul_control", "seagul_learn", "torch"), "seagul_control": ("seagul_learn", "torch")}
"""Each lower package -> the packages its modules must import without."""


def modules(package: object) -> list[str]:
    """Every module of ``package`` (sub-packages included), by dotted name."""
    name = package.__name__  # type: ignore[attr-defined]
    found = [name]
    for info in pkgutil.walk_packages(package.__path__, prefix=name + "."):  # type: ignore[attr-defined]
        found.append(info.name)
    return sorted(found)


def import_all_without(names: list[str], blocked: tuple[str, ...]) -> dict[str, str]:
    """Import every module of ``names`` in a subprocess where ``blocked`` cannot be imported; failures by module."""
    code = (
        "import importlib, json, sys, warnings\n"
        f"for blocked in {list(blocked)!r}:\n"
        "    sys.modules[blocked] = None\n"
        "failed = {}\n"
        f"for name in {names!r}:\n"
        "    try:\n"
        "        with warnings.catch_warnings():\n"
        "            warnings.simplefilter('ignore')\n"
        "            importlib.import_module(name)\n"
        "    except Exception as exc:\n"
        "        failed[name] = f'{type(exc).__name__}: {exc}'\n"
        "print(json.dumps(failed))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("package", [seagul_envs, seagul_control], ids=lambda p: p.__name__)
def test_every_module_of_a_lower_layer_imports_without_the_layers_above(package: object) -> None:
    names = modules(package)
    assert len(names) > 5  # the walk found the package's modules
    if package is seagul_control:  # the evaluation's parts: the policy kinds' builders and the starts
        assert {"seagul_control.evaluation", "seagul_control.policy_kinds", "seagul_control.starts"} <= set(names)
    failed = import_all_without(names, LOWER[package.__name__])  # type: ignore[attr-defined]
    assert failed == {}


def test_the_check_catches_an_upper_layer_import() -> None:
    """The subprocess check is not vacuous: a module that needs a blocked package is reported."""
    failed = import_all_without(["seagul_control.evaluation", "seagul_learn.policies"], ("torch",))
    assert list(failed) == ["seagul_learn.policies"]  # it loads value networks
    assert "import of torch halted" in failed["seagul_learn.policies"]
    failed = import_all_without(["seagul_envs.registration"], ("gymnasium",))  # an indirect import is caught too
    assert "import of gymnasium halted" in failed["seagul_envs.registration"]


def imported_packages(path: Path) -> set[str]:
    """The top-level packages every import statement of a source file names (at any depth in the file)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module.split(".")[0])
    return found


DEPRECATED_PATHS = {"seagul_envs/tasks/profile_legacy.py": ["seagul_learn"]}
"""Modules whose deprecated names still read an upper layer's data inside the function that serves them (and are
listed here so that a new one is a decision): ``TaskProfile.presets``/``train_recipe`` read
``seagul_learn.recipes``."""


@pytest.mark.parametrize("package", [seagul_envs, seagul_control], ids=lambda p: p.__name__)
def test_no_import_statement_of_a_lower_layer_names_an_upper_one(package: object) -> None:
    """Not even inside a function: the upper layers are reached by module path strings only (a policy kind's
    builder, a moved name's new module), apart from the deprecated paths listed in :data:`DEPRECATED_PATHS`."""
    name = package.__name__  # type: ignore[attr-defined]
    root = Path(package.__path__[0])  # type: ignore[attr-defined]
    sources = sorted(root.rglob("*.py"))
    assert sources
    offenders = {
        str(path.relative_to(root.parent)): sorted(imported_packages(path) & set(LOWER[name])) for path in sources
    }
    found = {path: bad for path, bad in offenders.items() if bad}
    assert found == {p: bad for p, bad in DEPRECATED_PATHS.items() if p.startswith(name + "/") and p in found}


# ------------------------------------------------------------------------------------------------ seagul_control.io
def test_io_is_public_and_its_old_private_name_is_the_same_module() -> None:
    """Every layer writes files through ``seagul_control.io`` (standard library only); ``seagul_control._io`` is
    the same module object, so patching either patches both."""
    code = (
        "import sys, seagul_control.io, seagul_control._io as old; "
        "from seagul_control import _io; "
        "assert old is _io is seagul_control.io, 'two modules'; "
        "bad = [m for m in ('torch', 'casadi', 'numpy', 'seagul_learn') if m in sys.modules]; "
        "sys.exit(f'imported {bad}' if bad else 0)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_json_files_are_written_atomically_with_the_callers_layout(tmp_path: Path) -> None:
    from seagul_control import io

    data = {"b": [1, 2.5], "a": float("nan"), "c": None}
    io.atomic_write_json(tmp_path / "sub" / "x.json", data, indent=1, sort_keys=True, newline=True)
    assert (tmp_path / "sub" / "x.json").read_text() == json.dumps(data, indent=1, sort_keys=True) + "\n"
    io.atomic_write_json(tmp_path / "y.json", data)
    assert (tmp_path / "y.json").read_text() == json.dumps(data)  # json.dumps' own layout by default
    back = io.read_json(tmp_path / "y.json")
    assert back["b"] == [1, 2.5] and back["a"] != back["a"]  # NaN round trip
    with pytest.raises(ValueError, match="Out of range float"):
        io.atomic_write_json(tmp_path / "z.json", data, allow_nan=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub", "y.json"]  # nothing written, no temp file left
    (tmp_path / "cut.json").write_text('{"a": [1, ')
    with pytest.raises(ValueError, match=r"cut\.json is not a JSON file"):
        io.read_json(tmp_path / "cut.json")


# ------------------------------------------------------------------------------------------- seagul_learn's names
def test_seagul_learns_public_names_resolve_and_the_config_parts_need_no_torch() -> None:
    """``import seagul_learn`` stays cheap: its names load their module on first use. The TrainConfig parts and the
    recipes module are plain data and importing them must not pull in torch (reading a recipe validates it as a
    TrainConfig, which does); every name of ``__all__`` then resolves (``UniformOptions`` to the samplers' class)."""
    code = (
        "import sys, seagul_learn as sl; "
        "from seagul_learn import LossConfig, NetworkConfig, RefitConfig, RuntimeConfig, ScheduleConfig, "
        "SelectionConfig, recipes; "
        "import seagul_learn.config_parts as parts; "
        "assert recipes is sys.modules['seagul_learn.recipes'], 'recipes is not the module'; "
        "assert (NetworkConfig, RuntimeConfig) == (parts.NetworkConfig, parts.RuntimeConfig); "
        "sys.exit('torch imported' if 'torch' in sys.modules else 0)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    import seagul_learn
    from seagul_learn import samplers

    assert seagul_learn.UniformOptions is samplers.UniformOptions
    assert seagul_learn.recipes.recipe("acrobot", "default")["network"]["hidden"] == [64, 64]
    assert {"recipes", "UniformOptions", "SelectionConfig"} <= set(seagul_learn.__all__)
    for name in seagul_learn.__all__:
        assert getattr(seagul_learn, name) is not None, name
    with pytest.raises(AttributeError, match="has no attribute 'NoSuchName'"):
        seagul_learn.NoSuchName  # noqa: B018


# ------------------------------------------------------------------------------- configuration without torch
TORCH_FREE = (
    "seagul_learn.config",
    "seagul_learn.recipes",
    "seagul_learn.config_parts",
    "seagul_learn.sampler_options",
)
"""Modules a configuration is built and parsed with (``TrainConfig``, the recipes, the samplers' options): the
command line and users' scripts read and check a configuration without paying torch's import."""


def modules_loaded_by(code: str) -> list[str]:
    """The modules of torch's family (``torch``, ``seagul_learn.value_network``) loaded after running ``code`` in a
    fresh interpreter, where no other test's imports can hide one."""
    watched = ["torch", "seagul_learn.value_network"]
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(set({watched!r}) & set(sys.modules))))"
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("module", TORCH_FREE)
def test_the_configuration_modules_import_without_torch(module: str) -> None:
    assert modules_loaded_by(f"import {module}") == []


def test_a_recipes_config_is_built_round_tripped_and_reparsed_without_torch() -> None:
    """What ``seagul train`` does before training: a task's recipe as a TrainConfig with overrides (the closed-loop
    sampler's options among them), its JSON form and back, without torch; the samplers' module, which runs the
    sampling on a value network, does load it (the probe sees an indirect import)."""
    code = (
        "from seagul_learn.config import TrainConfig\n"
        "from seagul_learn.sampler_options import ClosedLoopOptions\n"
        "config = TrainConfig.recipe('acrobot', sampler=ClosedLoopOptions(episodes=3))\n"
        "assert TrainConfig.from_dict(config.to_dict()) == config\n"
        "assert config.sampler == 'closed-loop' and config.sampler.episodes == 3\n"
    )
    assert modules_loaded_by(code) == []
    # The package's own names for them too (``seagul_learn.TrainConfig``, ``seagul_learn.ClosedLoopOptions``).
    package = "import seagul_learn as sl\nsl.TrainConfig.recipe('glider', sampler=sl.ClosedLoopOptions(episodes=2))\n"
    assert modules_loaded_by(package) == []
    assert modules_loaded_by("import seagul_learn.samplers") == ["seagul_learn.value_network", "torch"]
