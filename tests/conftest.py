"""Shared fixtures and helpers: small random policies for any env, written as real policy files; graph runs (in this
process, or as ``run_graph.py`` processes where the process is what a test is about) and the ROS processes they must
not leave behind; the nodes a test starts itself (an external policy, the documented one, a lone simulator); step
messages as the nodes send them; and the tests' own step-by-step sum of a log's episodes."""
from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

# pytest-xdist's worker (gw0, gw1, ...) and their number; one process without it
WORKER = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:])
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
# A test process never joins another run's ROS graph (the graph tests start real nodes); an id of the
# upper safe range (215-232), whose DDS ports keep clear of Linux's ephemeral ones. The workers of one suite
# count on from their parent's slot, so two of them never share one.
_SLOT = (os.getppid() if "PYTEST_XDIST_WORKER" in os.environ else os.getpid()) + WORKER
os.environ.setdefault("ROS_DOMAIN_ID", str(215 + _SLOT % 18))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
# Trainers write a user's files to $ARIL_DATA by default: the tests' go to a folder of their own, never the
# home of whoever runs them (the node processes the graph tests start inherit it).
os.environ["ARIL_DATA"] = tempfile.mkdtemp(prefix="aril_data-tests-")

from aril_ros.policy import MLPPolicy, meta_for_env, save_policy  # noqa: E402
from aril_ros.step import EpisodeStats  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

RUN_DOMAINS = range(1, 102)
"""The ids graph runs of the tests take (the test processes' own are 215-232)."""


def free_domain() -> int:
    """A domain no other aril_ros run holds; released so run_graph.py (domain:=N) can take it. Each worker takes
    from its own share of the ids (every WORKERS-th), so two workers never pick one between release and take."""
    from aril_ros_nodes.orchestrator import GraphError, allocate_domain

    for domain in RUN_DOMAINS[WORKER::WORKERS]:
        try:
            _, lock = allocate_domain(str(domain))
        except GraphError:  # held by another run
            continue
        lock.close()
        return domain
    raise GraphError(f"no free ROS domain id among {RUN_DOMAINS[WORKER::WORKERS]}")


SHARED_RUNS = {"recorded_files": "recorded-sensory-run", "recorded_run": "recorded-swimmer-run", "small_card": "ray"}
"""Module-scoped fixtures that make a graph run or a scorecard, and the ``xdist_group`` of the tests that use one:
on one worker it is made once, where tests spread over two workers would each make it. The scorecard's joins the
Ray tests' group, of which its two-node test is one."""


def pytest_collection_modifyitems(config, items):
    """Each test's ``xdist_group`` (its own, or :data:`SHARED_RUNS`'), in its id as pytest-xdist's ``loadgroup``
    reads it (``<id>@<group>``). pytest-xdist 3.8 writes it into ``item._nodeid``, which pytest 9 no longer reads
    (the id is ``item._id``): without this no group would keep its tests on one worker."""
    from _pytest.nodeid import NodeId

    for item in items:
        shared = [group for fixture, group in SHARED_RUNS.items() if fixture in item.fixturenames]
        if shared and not item.get_closest_marker("xdist_group"):
            item.add_marker(pytest.mark.xdist_group(shared[0]))
        groups = sorted({str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
                         for mark in item.iter_markers("xdist_group")})
        if getattr(config.option, "loadgroup", False) and groups and "@" not in item.nodeid:
            item._id = NodeId.parse(f"{item.nodeid}@{'_'.join(groups)}")


# ------------------------------------------------------------------------------------------ policies
def random_policy(env_id: str, seed: int = 0, hidden=(32, 32)) -> MLPPolicy:
    torch.manual_seed(seed)  # test-only: the fixture's weights, not library randomness
    return MLPPolicy(meta_for_env(env_id, hidden=list(hidden), provenance={"made_by": "tests"})).eval()


@pytest.fixture
def make_policy():
    return random_policy


def policy_files(tmp_path, env_id):
    """A random policy and a random expert for ``env_id``, as files in ``tmp_path``: (policy, expert)."""
    return (save_policy(random_policy(env_id, seed=1), tmp_path / "policy.pt"),
            save_policy(random_policy(env_id, seed=2), tmp_path / "expert.pt"))


class AnswersOnly:
    """A black box: it answers ``act``, counting the rows it was asked (``asked``), and refuses every other access
    (weights, gradients); the policy lives in a closure, where no attribute lookup reaches it."""

    def __init__(self, policy):
        answer = policy.act
        self.asked = 0

        def act(obs):
            self.asked += len(obs)
            return answer(obs)

        self.act = act

    def __getattr__(self, name):
        raise AssertionError(f"a black-box attack reached for the victim's {name!r}")


# ---------------------------------------------------------------------------------------- graph runs
def ros_env(domain: int) -> dict:
    return {**os.environ, "ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


ROS_PROCESS_MARKS = (b"aril_ros_nodes", b"run_graph", b"rclpy")
"""What a ROS process's command line shows: one of our nodes or orchestrator, or a test's own ``python -c``
node (its code imports rclpy). A helper this test process started during an in-process run (multiprocessing's
resource tracker) inherits the run's ROS_DOMAIN_ID too, but is no node and lives as long as this process."""


def processes_in_domain(domain: int, besides=()) -> list[str]:
    """ROS processes (but this one and ``besides``) whose environment puts them in ``domain``, as
    ``"<pid>: <command line>"``: none after a run."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) in (os.getpid(), *besides):
            continue
        try:
            environ = (entry / "environ").read_bytes().split(b"\0")
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if f"ROS_DOMAIN_ID={domain}".encode() in environ and any(mark in cmdline for mark in ROS_PROCESS_MARKS):
            command = cmdline.replace(b"\0", b" ").decode(errors="replace")
            found.append(f"{entry.name}: {command[:200]}")
    return found


def run_graph(*args, domain=None, timeout=180, besides=(), process=False) -> subprocess.CompletedProcess:
    """``python run_graph.py *args domain:=<domain>`` (a free domain unless given), from the checkout: its exit
    code and what it wrote. It runs in this process, as the script runs it after its bootstrap
    (:func:`aril_ros_nodes.run_graph.main`), unless ``process``: a test about the script's process itself (its
    bootstrap, its exit, what the process writes) asks for a real one. Either way no ROS process but ``besides``
    is left in the domain after."""
    domain = free_domain() if domain is None else domain
    argv = [*args, f"domain:={domain}"]
    if process:
        out = subprocess.run([sys.executable, str(ROOT / "run_graph.py"), *argv], capture_output=True, text=True,
                             timeout=timeout, cwd=ROOT)
    else:
        out = run_graph_here(argv, timeout)
    assert processes_in_domain(domain, besides) == [], "a node outlived its run"
    return out


def run_graph_here(argv: list[str], timeout: float) -> subprocess.CompletedProcess:
    """:func:`aril_ros_nodes.run_graph.main` in this process, from the checkout's folder, with file descriptors 1
    and 2 caught as a process's output would be (prints, and what rclpy's C logging writes), and an exception it
    lets through printed as the interpreter would, exit code 1. After ``timeout`` seconds it is stopped with
    ``subprocess.TimeoutExpired``, as the process would be. The environment and the signal handlers are this
    process's again after."""
    from aril_ros_nodes.launcher import STOP_SIGNALS  # the orchestrator catches them while it runs
    from aril_ros_nodes.run_graph import main

    environ = dict(os.environ)
    handlers = {sig: signal.getsignal(sig) for sig in (*STOP_SIGNALS, signal.SIGALRM)}

    def time_out(signum, frame):
        raise subprocess.TimeoutExpired(["run_graph.py", *argv], timeout)

    with caught_output() as output:
        signal.signal(signal.SIGALRM, time_out)
        signal.setitimer(signal.ITIMER_REAL, timeout)
        try:
            with contextlib.chdir(ROOT):
                code = main(argv)
        except subprocess.TimeoutExpired:
            raise
        except Exception:  # noqa: BLE001 - what an uncaught exception does to the script: a traceback, exit 1
            import traceback

            traceback.print_exc()
            code = 1
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            for sig, handler in handlers.items():
                signal.signal(sig, handler)
    assert dict(os.environ) == environ, "the run left this process's environment changed"
    return subprocess.CompletedProcess(["run_graph.py", *argv], code, *output)


@contextlib.contextmanager
def caught_output():
    """File descriptors 1 and 2, and ``sys.stdout``/``sys.stderr`` on them, into files of their own for the
    block; yields a list that holds (stdout, stderr) as text after it."""
    output = []
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with tempfile.TemporaryFile() as out_file, tempfile.TemporaryFile() as err_file:
        streams = [open(f.fileno(), "w", buffering=1, encoding="utf-8", errors="replace", closefd=False)
                   for f in (out_file, err_file)]
        try:
            os.dup2(out_file.fileno(), 1)
            os.dup2(err_file.fileno(), 2)
            with contextlib.redirect_stdout(streams[0]), contextlib.redirect_stderr(streams[1]):
                yield output
        finally:
            for stream in streams:
                stream.close()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            for f in (out_file, err_file):
                f.seek(0)
                output.append(f.read().decode(errors="replace"))


def summary_of(out) -> dict:
    """A successful run's JSON summary line."""
    import json

    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


COMPARED = ("true_obs", "obs", "delta", "action", "expert_action", "reward")


def assert_same_steps(run, traj) -> None:
    """Every logged step of every episode equals the engine's, to the bit."""
    for e in range(len(traj.length)):
        rows = run.episodes == e
        assert rows.sum() == traj.length[e]
        for name in COMPARED:
            np.testing.assert_array_equal(getattr(run, name)[rows], getattr(traj, name)[e, : traj.length[e]],
                                          err_msg=f"{name}, episode {e}")


def episode_stats(run) -> list[EpisodeStats]:
    """The figures of each episode of a log (a :class:`aril_ros.runlog.reader.RunLog`), summed here step by step
    from its rows, in the order of first appearance: the tests' own sum, beside the one the recorder took from the
    live messages into the log's end record."""
    stats: dict[int, EpisodeStats] = {}
    for row, e in enumerate(run.episodes):
        stats.setdefault(int(e), EpisodeStats(int(e))).add(run.reward[row], run.action[row], run.expert_action[row],
                                                           run.delta[row],
                                                           done=run.terminated[row] or run.truncated[row])
    return list(stats.values())


# ------------------------------------------------------------------------------- nodes a test starts
EXTERNAL_POLICY = r"""
# A policy node written from the documented topics alone: no aril_ros import.
import sys
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

behaviour, act_dim = sys.argv[1], int(sys.argv[2])
rclpy.init()
node = Node("my_policy")
qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
pub = node.create_publisher(JointState, "action", qos)
answered = 0

def on_observation(msg):
    global answered
    if behaviour == "silent" or (behaviour == "dies" and answered == 5):
        if behaviour == "dies":
            raise SystemExit(3)
        return
    action = np.tanh(0.5 * np.asarray(msg.position[:act_dim]))
    if behaviour == "short":
        action = action[:1]
    if behaviour == "nan":
        action[0] = np.nan
    pub.publish(JointState(header=msg.header, effort=action.tolist()))
    answered += 1

node.create_subscription(JointState, "observation", on_observation, qos)
rclpy.spin(node)
"""


def start_external(behaviour: str, domain: int, act_dim: int = 6):
    return subprocess.Popen([sys.executable, "-c", EXTERNAL_POLICY, behaviour, str(act_dim)],
                            env=ros_env(domain), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def run_with_external(behaviour, tmp_path, *args):
    """A HalfCheetah sensory run of one 50-step episode (recorded to ``tmp_path/run.mcap``) whose policy is an
    :data:`EXTERNAL_POLICY` node behaving as ``behaviour``."""
    domain = free_domain()
    external = start_external(behaviour, domain)
    try:
        _, expert = policy_files(tmp_path, "HalfCheetah-v5")
        return run_graph("mode:=sensory", "policy:=external", f"expert:={expert}", "episodes:=1", "horizon:=50",
                         "eps:=0.1", f"record:={tmp_path / 'run.mcap'}", "step_timeout:=4", *args, domain=domain,
                         besides=[external.pid])
    finally:
        external.kill()
        external.wait()


CONTRACT = ROOT / "msgs_doc" / "README.md"
"""The interface contract, whose "Write your own policy node" section gives a user's policy node."""


def documented_node() -> str:
    """The code block of the contract's "Write your own policy node" section, as a user copies it."""
    section = CONTRACT.read_text().split("\n## Write your own policy node\n", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.DOTALL).group(1)


def start_node(code: str, domain: int, tmp_path, *ros_args: str):
    """``code`` as the user runs it: a file of its own, in the run's domain. Its stderr goes to
    ``my_policy.stderr`` beside it, with Python's fault handler on: what :func:`stop` reports of a node that hangs."""
    path, stderr_path = tmp_path / "my_policy.py", tmp_path / "my_policy.stderr"
    path.write_text(code)
    with stderr_path.open("w") as stderr:
        node = subprocess.Popen([sys.executable, str(path), "--ros-args", *ros_args],
                                env={**ros_env(domain), "PYTHONFAULTHANDLER": "1"}, stdout=subprocess.DEVNULL,
                                stderr=stderr)
    node.stderr_path = stderr_path
    return node


def stop(node) -> None:
    """A node a test started: SIGINT, as Ctrl-C stops it. One that has not ended within 10 s is stopped for good,
    and ``node.hung`` says what it was doing (empty for a node that ended): its threads' kernel waits, their native
    stacks where gdb is installed, and Python's tracebacks of them (SIGABRT, which the fault handler dumps to its
    stderr). A test that asserts the node's clean exit reports it, so that a hang seen once names where it hung."""
    node.hung = ""
    node.send_signal(signal.SIGINT)
    try:
        node.wait(10)
        return
    except subprocess.TimeoutExpired:
        pass
    node.hung = f"the node (pid {node.pid}) had not ended 10 s after SIGINT\n" + threads_of(node.pid)
    node.send_signal(signal.SIGABRT)
    try:
        node.wait(10)
    except subprocess.TimeoutExpired:
        node.kill()
        node.wait()
    node.hung += "its stderr:\n" + node.stderr_path.read_text(errors="replace")[-20_000:]


def threads_of(pid: int) -> str:
    """Each thread of the process ``pid``: its name, kernel state and wait channel; and, where gdb is installed,
    every thread's native stack (what a thread waits on inside a library, where a Python traceback stops)."""
    lines = []
    for task in sorted(Path(f"/proc/{pid}/task").glob("*")):
        try:
            state = (task / "stat").read_text().rsplit(")", 1)[1].split()[0]
            lines.append(f"thread {task.name} {(task / 'comm').read_text().strip()}: state {state}, "
                         f"waiting in {(task / 'wchan').read_text() or '-'}")
        except OSError:  # the thread ended meanwhile
            continue
    if shutil.which("gdb"):
        try:
            lines.append(subprocess.run(["gdb", "-p", str(pid), "-batch", "-ex", "thread apply all bt"],
                                        capture_output=True, text=True, timeout=60).stdout[-20_000:])
        except subprocess.TimeoutExpired:
            lines.append("gdb had not printed the stacks within 60 s")
    return "\n".join(lines) + "\n"


@contextlib.contextmanager
def simulator_and_prober(cwd=None):
    """A Swimmer simulator node alone in a fresh domain (started from ``cwd``: any folder, it is installed)
    and a node of this process in that domain with its executor; both stopped after."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    domain = free_domain()
    sim = subprocess.Popen([sys.executable, "-m", "aril_ros_nodes.simulator_node", "--ros-args", "-p",
                            "env:=Swimmer-v5"], env=ros_env(domain), cwd=cwd, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    context = rclpy.Context()
    rclpy.init(args=[], context=context)
    node = rclpy.create_node("prober", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield sim, node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        sim.send_signal(signal.SIGINT)
        sim.wait(10)


# ------------------------------------------------------------------------------------------------ Ray
@contextlib.contextmanager
def local_ray(cpus: int = 2):
    """One embedded local Ray (``cpus`` CPUs) for the commands a test runs in the block, which join it
    (:func:`aril_ros.sweep.connect`) instead of each starting and stopping a Ray of its own, and their worker
    processes with it; shut down after. Started inside the block's environment: its workers inherit it."""
    from aril_ros.sweep import connect

    ray, started = connect("", cpus)
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


# ------------------------------------------------------------------------------------- step messages
def cdr(header, names, **values) -> bytes:
    """A JointState of ``header`` as the nodes send it, serialised."""
    from rclpy.serialization import serialize_message

    from aril_ros_nodes.common import joint_state

    return serialize_message(joint_state(header, names, **values))


def step_messages(tag, stamp: int, done: bool) -> dict[str, bytes]:
    """Every step topic's message of step ``tag`` (an :class:`aril_ros.protocol.StepTag`) of a two-value toy env,
    as the nodes send them."""
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock

    from aril_ros import protocol as P
    from aril_ros_nodes.common import step_header

    header = step_header(tag, stamp)
    state = [float(tag.step), 1.0]
    return {P.CLOCK: serialize_message(Clock(clock=header.stamp)), P.PHYSICS: cdr(header, ["q"], position=[0.0]),
            P.STATE: cdr(header, ["x", "y"], position=state), P.PERTURBATION: cdr(header, ["x", "y"], position=[0, 0]),
            P.OBSERVATION: cdr(header, ["x", "y"], position=state), P.ACTION: cdr(header, ["u"], effort=[0.5]),
            P.EXPERT_ACTION: cdr(header, ["u"], effort=[0.0]),
            P.REWARD: cdr(header, P.REWARD_NAMES, position=[1.0, 0.0, float(done)])}
