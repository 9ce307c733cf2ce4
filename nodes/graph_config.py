"""The arguments of a graph run (``run_graph.py``) and the run they make, checked before any node starts: the
attack and its settings, and each file that acts in it (policy, expert, adversary), loaded once, here, for its
metadata and its digest (the nodes load it again in their own processes)."""
from __future__ import annotations

import datetime
from dataclasses import dataclass
from pathlib import Path

from aril_ros import __version__
from aril_ros.adversary_net import AdversaryNet
from aril_ros.args import ArgumentError, arg, check_ranges
from aril_ros.attacks import iteration_settings, learned_adversary, learned_eps, queries_victim
from aril_ros.envs import HORIZON, ObsLayout, layout_of
from aril_ros.policy import PolicyMeta, load_policy, policy_file
from aril_ros.provenance import git_revision, portable
from aril_ros.registry import (ATTACKS, BUNDLED_NAMES, BUNDLED_POLICIES, DEFAULT_ENV, DEFAULT_POLICY, DEFENSES, MAX_EPS,
                               MODES, PER_MODE_POLICIES, WHITE_BOX, attack_budget, choose_attack)
from aril_ros.render import frame_size
from aril_ros.runlog.layout import TIMING_KEY
from aril_ros.sweep import digest_of
from aril_ros.timing import TimingAttack, timing_arg
from aril_ros_nodes.launcher import GraphError, domain_candidates


@dataclass
class GraphConfig:
    """Arguments of ``run_graph.py``."""

    mode: str = arg("sensory", f"one of {', '.join(MODES)}")
    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    attack: str = arg("", f"one of {', '.join(ATTACKS)} (default: none when clean; attacked, the strongest bundled "
                          "for the policy: the ARIL-A trained against it, random where none is bundled)")
    eps: float = arg(0.0, f"L-infinity bound of the perturbation on the zero-order entries, at most {MAX_EPS} "
                          "(0: the calibrated one for env and mode, bundled with aril_ros; aril_a: its adversary's)")
    k: int = arg(0, "iterations of fgsm_k, spsa and fd_fgsm (0: the attack's default)", low=0, high=1000)
    samples: int = arg(0, "spsa: random directions per iteration, each asked at +- (0: the attack's default)",
                       low=0, high=1000)
    attack_file: str = arg("", "aril_a: the adversary file (from aril train-adversary); transfer: the surrogate file "
                                "(aril fit-surrogate)")
    search: int = arg(0, "aril_a: query-time search over this many candidates drawn from the adversary, the policy "
                         "node asked about all (probes), the most damaging applied (0: no search)", low=0, high=1000)
    probe_batches: bool = arg(True, "query-based attacks: ask a step's probes in one message (a probe batch) where the "
                                    "policy node declares its probe_batches parameter true, as the bundled one does "
                                    "(false: one message a probe, as to a node that does not)")
    baseline: bool = arg(True, "run_graph.py, an attacked mode: the clean return of the same episodes beside the "
                               "attacked one (the engine's; an external node's through a clean run of the graph)")
    rescale: bool = arg(False, "aril_a at an eps:= other than its adversary's: scale its perturbation by eps / its eps "
                               "(an eps sweep with one adversary)")
    episodes: int = arg(2, "episodes to run (env seeds seed, seed+1, ...)", low=1, high=100_000)
    # seeds are non-negative (numpy, gymnasium), and seed + episodes stays within 32 bits
    seed: int = arg(0, "seed of the first episode and of the attack noise", low=0, high=2**31 - 1)
    policy: str = arg("bundled", f"bundled (the default bundled policy: the {DEFENSES[DEFAULT_POLICY]} learner), "
                                 f"{', '.join(BUNDLED_POLICIES)} ({' and '.join(PER_MODE_POLICIES)}: the one trained "
                                 "against mode:=), a policy file, or external (start none, wait for one)")
    expert: str = arg("expert", "the labelling expert: a bundled name or a policy file")
    horizon: int = arg(HORIZON, "steps per episode", low=1, high=1_000_000)
    record: str = arg("", "MCAP file to record to, created anew (default: runs/<time>-<env>-<mode>-<random>.mcap; "
                          "off: no file)")
    domain: str = arg("auto", "ROS_DOMAIN_ID for this run: 0-101 or 215-232 (auto: a free one of those, held "
                              "by a lock file)")
    # below a second a loaded machine's DDS discovery or a slow step would stop a healthy run; an hour is a typo
    connect_timeout: float = arg(30.0, "seconds to wait for every node (and an external policy) to connect",
                                 low=1.0, high=3600.0)
    step_timeout: float = arg(10.0, "seconds without progress before the run is stopped as stuck", low=1.0,
                              high=3600.0)
    render: bool = arg(False, "record camera frames: the simulator renders offscreen (MuJoCo on the CPU, MUJOCO_GL=egl "
                              "unless set) and publishes sim/camera/image/compressed (JPEG), the log keeps them")
    render_every: int = arg(5, "render:=true: a frame every this many steps", low=1)
    render_size: str = arg("320x240", "render:=true: frame width x height in pixels")
    live: str = arg("off", "serve the run to Foxglove as it runs (docs/live-and-export.md): on, wait (hold the first step "
                           "until a viewer subscribes) or off")
    live_port: int = arg(8765, "live:=on|wait: the WebSocket port of the live view (0: a free one, printed)", low=0,
                         high=65535)
    live_host: str = arg("127.0.0.1", "live:=on|wait: the address the live view listens on (0.0.0.0: every "
                                      "interface, for a viewer on another machine)")
    delay: int = timing_arg("delay", "clean and sensory, played by the attacker node")
    drop: float = timing_arg("drop", "clean and sensory, played by the attacker node")
    action_delay: int = timing_arg("action_delay", "every mode, played by the simulator node as the attacker node's "
                                                   "attack/timing says")
    timing: str = timing_arg("timing")
    timing_file: str = timing_arg("timing_file")


LIVE = ("off", "on", "wait")
"""What ``live:=`` takes."""
ONE_ATTACKS_ARGUMENTS = {"attack_file": ("aril_a", "transfer"), "search": ("aril_a",), "rescale": ("aril_a",),
                         "samples": ("spsa",)}
"""Arguments that some attacks alone read, and those attacks."""


@dataclass(frozen=True)
class GraphRun:
    """A checked graph run: what its arguments make of it, and what acts in it."""

    cfg: GraphConfig
    attack: str
    why: str
    """why this attack, when the arguments named none"""
    eps: float
    probes: bool
    """whether the attack asks the policy node (through the attacker's probe client)"""
    layout: ObsLayout
    policy_meta: PolicyMeta | None
    """None for an external policy node"""
    expert_meta: PolicyMeta
    adversary: Path | None
    """aril_a's adversary file, absolute"""
    files: dict[str, dict | None]
    """each acting file's path and SHA-256 (None: no file acts, e.g. an external policy, an attack of no file)"""
    timing: TimingAttack | None = None
    """the timing attack the attacker node plays, if any"""

    @property
    def action_listeners(self) -> int:
        """Who listens on action: the simulator, the recorder and, when the attack queries, the attacker's probe
        client; the policy node waits for all of them, or step 0's action may reach only some."""
        return 2 + self.probes

    def attack_settings(self) -> dict:
        """Every setting of the attack as it runs (k and samples: the attack's own defaults for 0)."""
        cfg = self.cfg
        return {"attack": self.attack, "eps": self.eps, **iteration_settings(self.attack, cfg.k, cfg.samples),
                "search": cfg.search, "rescale": cfg.rescale, "seed": cfg.seed}

    def metadata(self) -> dict:
        """The log's run record (:data:`aril_ros.runlog.layout.RUN`)."""
        cfg = self.cfg
        return {
            "env": cfg.env, "mode": cfg.mode, "attack": self.attack, "eps": self.eps, "seed": cfg.seed,
            "episodes": cfg.episodes, "horizon": cfg.horizon, "policy": cfg.policy, "expert": cfg.expert,
            "attack_settings": self.attack_settings(), "files": self.files,
            "policy_provenance": self.policy_meta.provenance if self.policy_meta else "external",
            "expert_provenance": self.expert_meta.provenance, "obs_names": list(self.layout.names),
            "zero_order": self.layout.zero_order_mask.tolist(),
            "action_names": list(self.layout.action_names), "aril_ros": __version__,
            "git_revision": git_revision(), "created": datetime.datetime.now().isoformat(timespec="seconds"),
            **({TIMING_KEY: self.timing.record()} if self.timing else {}),
        }

    def node_params(self) -> dict[str, dict]:
        """Each node's parameters; no policy node for an external policy."""
        cfg = self.cfg
        common = {"env": cfg.env, "mode": cfg.mode}
        policy, expert = (node_path(name) for name in (cfg.policy, cfg.expert))
        params = {
            "simulator": {**common, "horizon": cfg.horizon,
                          **({"render_every": cfg.render_every, "render_size": cfg.render_size} if cfg.render else {}),
                          **({"action_delay": cfg.action_delay} if cfg.action_delay else {})},
            "attacker": {**common, "attack": self.attack, "eps": float(self.eps), "seed": cfg.seed,
                         "k": cfg.k, "samples": cfg.samples, "search": cfg.search, "expert": expert,
                         "rescale": cfg.rescale, "probe_batches": cfg.probe_batches,
                         **({"victim": policy} if self.attack in WHITE_BOX else {}),
                         **({"delay": cfg.delay, "drop": float(cfg.drop), "action_delay": cfg.action_delay,
                             "timing": cfg.timing} if self.timing else {}),
                         **({"timing_file": str(Path(cfg.timing_file).resolve())} if cfg.timing_file else {}),
                         **({"attack_file": str(self.adversary)} if self.adversary else {})},
            "expert": {"env": cfg.env, "expert": expert},
        }
        if cfg.policy != "external":
            params["policy"] = {**common, "policy": policy, "listeners": self.action_listeners}
        return params


def plan_run(cfg: GraphConfig) -> GraphRun:
    """The run ``cfg`` asks for, every argument checked and every acting file loaded: a bad one is refused (a
    ValueError, or a GraphError naming what the graph cannot do) before any process starts."""
    check_ranges(cfg)
    domain_candidates(cfg.domain)  # a bad id is refused here, before any file is loaded
    # a bad mode or attack: a ValueError naming both; none named: the strongest bundled for the policy
    choice = choose_attack(cfg.env, cfg.mode, cfg.policy, cfg.attack, cfg.attack_file)
    for name, users in ONE_ATTACKS_ARGUMENTS.items():  # elsewhere it would be silently ignored
        if getattr(cfg, name) and choice.name not in users:
            raise ArgumentError(f"{name}:={getattr(cfg, name)} is used by "
                                f"{' and '.join(f'attack:={u}' for u in users)} only, got attack:={choice.name}")
    if cfg.render:
        frame_size(cfg.render_size)
    if cfg.live not in LIVE:
        raise ArgumentError(f"live:= is one of {', '.join(LIVE)}, got {cfg.live!r}")
    timing = TimingAttack.of(cfg)
    if (cfg.delay or cfg.drop) and cfg.mode == "physical":
        raise GraphError("delay:= and drop:= are played by the attacker node on the observation it publishes, "
                         "which in mode physical the simulator publishes: give mode:=clean or sensory (the engine, "
                         "aril eval, plays them in every mode)")
    if choice.name in WHITE_BOX and cfg.policy == "external":
        raise GraphError(f"attack:={choice.name} is white-box and needs the victim's weights; an external "
                         "policy can be attacked with a black-box one: "
                         + ", ".join(a for a in ATTACKS if a not in (*WHITE_BOX, "none")))
    layout = layout_of(cfg.env)
    if timing.chooser == "learned":  # a missing file, or one of another budget or env, refused before any node starts
        timing.timeline(1, layout.obs_dim, layout.act_dim, [])
    eps = attack_budget(cfg.env, cfg.mode, choice.name, cfg.eps)
    adversary, adversary_net = _adversary(cfg, choice.name, choice.file)
    if adversary_net is not None:  # its file's eps, or the one it is rescaled to
        eps = learned_eps(adversary_net, cfg.eps, cfg.rescale)
    expert = policy_file(cfg.expert, cfg.env)
    expert_meta = load_policy(expert, cfg.env).meta
    policy = None if cfg.policy == "external" else policy_file(cfg.policy, cfg.env, cfg.mode)
    policy_meta = None if policy is None else load_policy(policy, cfg.env).meta
    return GraphRun(cfg=cfg, attack=choice.name, why=choice.why, eps=eps,
                    probes=queries_victim(choice.name, adversary_net, cfg.search), layout=layout,
                    policy_meta=policy_meta, expert_meta=expert_meta, adversary=adversary,
                    files={"policy": file_record(policy), "expert": file_record(expert),
                           "adversary": file_record(adversary),
                           **({"timing_adversary": file_record(Path(cfg.timing_file))} if cfg.timing_file else {})},
                    timing=timing if timing.budget.any else None)


def _adversary(cfg: GraphConfig, attack: str, file: str) -> tuple[Path | None, AdversaryNet | None]:
    """aril_a's adversary file (``file``, else the bundled one) and network, or transfer's surrogate file and no
    network; a missing or mismatched file is refused here. None for any other attack."""
    if attack == "transfer":
        if not file:
            raise ArgumentError("attack:=transfer runs FGSM^k on a surrogate of the policy: pass its file as "
                                "attack_file:= (aril fit-surrogate)")
        load_policy(file, cfg.env)
        return Path(file).resolve(), None
    if attack != "aril_a":
        return None, None
    path, net = learned_adversary(cfg.env, cfg.mode, file, cfg.eps, cfg.rescale)
    return Path(path).resolve(), net


def file_record(path: Path | None) -> dict | None:
    """How the log records a file that acts in the run: its path (inside the checkout or the installed package,
    relative to it: ``aril_ros/data/...``) and its SHA-256."""
    if path is None:
        return None
    return {"path": portable(str(Path(path).resolve())), "sha256": digest_of(Path(path).read_bytes())}


def node_path(name: str) -> str:
    """What a node is given for a policy: a bundled name as it is (the node resolves it, the per-mode
    ones with its ``mode``), a file as an absolute path (a node need not share the caller's folder)."""
    return name if name in (*BUNDLED_NAMES, "external") else str(Path(name).resolve())
