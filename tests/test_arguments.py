"""Every number a user types is held to a range before anything runs: one line naming the argument and
the range, exit 2, no traceback (``aril_ros.args.check_ranges``, called by ``parse_args``)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
import typing

import pytest

from aril_ros import plugins
from aril_ros.args import ArgumentError, arg, check_ranges, parse_args
from aril_ros.benchmarks.adversary import AdversaryBenchConfig
from aril_ros.benchmarks.engine import BenchConfig
from aril_ros.benchmarks.sweep import SweepBenchConfig
from aril_ros.cli import COMMANDS, command, main

COMMAND_CONFIGS = {name: command(name).config for name in [*COMMANDS, *plugins.names("aril_ros.commands")]}
BENCHMARK_CONFIGS = {"engine": BenchConfig, "adversary": AdversaryBenchConfig, "sweep": SweepBenchConfig}


@pytest.mark.parametrize("name, config", [*COMMAND_CONFIGS.items(), *BENCHMARK_CONFIGS.items()])
def test_every_number_of_every_command_has_a_range_its_default_lies_in(name, config):
    types = typing.get_type_hints(config)
    unbounded = [f.name for f in dataclasses.fields(config) if types[f.name] in (int, float)
                 and (f.metadata.get("low") is None or f.metadata.get("high") is None)]
    assert unbounded == [], f"{name}: numeric arguments without a low..high range"
    check_ranges(config())  # the defaults are allowed values


@dataclasses.dataclass
class Sample:
    count: int = arg(5, "a count", low=1, high=10)
    rate: float = arg(0.5, "a rate", low=0.0)
    label: str = arg("x", "not a number: no range")


@pytest.mark.parametrize("argv, message", [
    (["count:=0"], "count:=0 is out of range: allowed 1..10"),
    (["count:=11"], "count:=11 is out of range: allowed 1..10"),
    (["rate:=-0.1"], "rate:=-0.1 is out of range: allowed >= 0.0"),
    (["rate:=nan"], "rate:=nan is out of range: allowed >= 0.0"),
])
def test_a_value_out_of_its_range_is_refused_naming_argument_value_and_range(argv, message):
    with pytest.raises(ArgumentError) as refused:
        parse_args(Sample, argv)
    assert str(refused.value) == message


def test_the_ends_of_a_range_are_allowed():
    assert (parse_args(Sample, ["count:=1"]).count, parse_args(Sample, ["count:=10"]).count) == (1, 10)
    assert parse_args(Sample, ["rate:=1e9"]).rate == 1e9


@pytest.mark.parametrize("argv, message", [
    (["eval", "episodes:=0"], "aril eval: error: episodes:=0 is out of range: allowed 1..100000"),
    (["eval", "episodes:=-1"], "aril eval: error: episodes:=-1 is out of range: allowed 1..100000"),
    (["eval", "n_envs:=0"], "aril eval: error: n_envs:=0 is out of range: allowed 1..1024"),
    (["eval", "eps:=2"], "aril eval: error: eps:=2.0 is out of range: allowed 0.0..1.0"),
    (["train-learner", "seed:=1000"], "aril train-learner: error: seed:=1000 is out of range: allowed 0..999"),
    (["render", "width:=0"], "aril render: error: width:=0 is out of range: allowed 16..4096"),
])
def test_aril_refuses_an_out_of_range_number_in_one_line(argv, message, capsys):
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert (out, err) == ("", message + "\n")


@pytest.mark.slow
def test_aril_eval_episodes_0_in_a_fresh_process_is_one_line_and_exit_2():
    """The issue's case: it ended in a ZeroDivisionError traceback after numpy warnings."""
    done = subprocess.run([sys.executable, "-m", "aril_ros", "eval", "env:=Swimmer-v5", "episodes:=0"],
                          capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == "aril eval: error: episodes:=0 is out of range: allowed 1..100000\n"


@pytest.mark.slow
def test_a_benchmark_module_refuses_an_out_of_range_number_in_one_line():
    done = subprocess.run([sys.executable, "-m", "aril_ros.benchmarks.engine", "steps:=0"], capture_output=True,
                          text=True, timeout=120)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == ("python -m aril_ros.benchmarks.engine: error: steps:=0 is out of range: "
                           "allowed 1..1000000000\n")
