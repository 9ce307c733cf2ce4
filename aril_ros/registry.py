"""The vocabulary of the testbed and where its bundled files live: every name is defined here once.

Modes, attacks, defenses and the paper's envs are named here; every other module, the ROS nodes
included, takes them from here. Bundled files are package data, found from the installed package
(never from a checkout's folders)::

    aril_ros/data/<policy>/<env>.pt                     expert, bc, dagger, dart, gail
    aril_ros/data/<policy>/<env>-<mode>.pt              dr, aril (trained against one attack mode)
    aril_ros/data/adversary/<env>-<mode>.pt             ARIL-A against the bundled DAgger learner
    aril_ros/data/directed-adversary/<env>-<mode>.pt    directed ARIL-A (policy:=directed) against it
    aril_ros/data/defense-adversary/<env>-<mode>-<defense>.pt   ARIL-A against each other defense
    aril_ros/data/eps_calibration.json                  the eps per env and mode (aril calibrate-eps)

A user's own trained files go to the user data folder (:func:`user_data_dir`: ``$ARIL_DATA``, by default
``~/.local/share/aril_ros``) in the same layout, never into the installed package. A name resolves to the
bundled file first and to the user's where nothing is bundled (``policy:=expert env:=Hopper-v5`` once
``aril train-expert env:=Hopper-v5`` has run), so the figures of the bundled envs never change behind a
user's back.

This module imports neither torch nor MuJoCo.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

DATA_DIR = Path(__file__).resolve().parent / "data"
CALIBRATION_NAME = "eps_calibration.json"
CALIBRATION = DATA_DIR / CALIBRATION_NAME

PAPER_ENVS = ("HalfCheetah-v5", "Ant-v5", "Swimmer-v5")
DEFAULT_ENV = PAPER_ENVS[0]

MODES = ("clean", "sensory", "physical")
ATTACKED_MODES = ("sensory", "physical")

ATTACKS = {"none": "clean", "random": "random", "fgsm": "FGSM", "fgsm_k": "FGSM^k", "spsa": "SPSA^k",
           "fd_fgsm": "FGSM by finite differences",
           "aril_a": "ARIL-A", "transfer": "FGSM^k on a surrogate"}
"""Every attack by name, with the name tables print."""
SEARCH_ROW = "aril_a_search"
"""A row of the tables and the scorecard: aril_a with query-time search (``search:=K`` candidates a step)."""
DIRECTED_ROW = "aril_a_directed"
"""A row of the attack tables and the scorecard: aril_a with a directed adversary (``policy:=directed``: a direction
in the victim's action space, turned into a perturbation by finite differences of its answers)."""
SCORECARD_ATTACKS = {**ATTACKS, "zoo": "ARIL-A from the zoo", SEARCH_ROW: "ARIL-A + search",
                     DIRECTED_ROW: "ARIL-A, directed"}
"""What a scorecard's and a table's rows name: the attacks, and three ways the black-box pipeline runs aril_a (an
adversary of the zoo as it is; its own with query-time search; its directed one)."""


def row_attack(row: str) -> str:
    """The attack a table's or a scorecard's row runs: aril_a for the zoo's row, ARIL-A + search and directed ARIL-A,
    which differ from the ARIL-A row only in the adversary file and the search; every other row is its attack."""
    return "aril_a" if row in ("zoo", SEARCH_ROW, DIRECTED_ROW) else row


SURROGATE_ATTACKS = ("transfer",)
"""Black-box attacks that compute on a surrogate of the victim (``attack_file``), never asking the victim."""
TABLE_SEARCH = 16
"""Candidates of ARIL-A's query-time search in the tables' ARIL-A + search rows (the attack tables', the report's)."""
WHITE_BOX = ("fgsm", "fgsm_k")
"""Attacks that need the victim's weights (gradients)."""
QUERY_ATTACKS = ("spsa", "fd_fgsm")
"""Black-box attacks that always query the victim's actions (aril_a does when its adversary takes
actions or searches)."""
THREATS = ("random", "fgsm", "fgsm_k", "spsa", "aril_a")
"""The attacks a defense is judged under: its worst one is its figure in the defense tables."""

DEFENSES = {"dagger": "DAgger", "gail": "GAIL", "dr": "DR", "dart": "DART", "aril": "ARIL", "bc": "BC"}
"""The bundled learners, in the paper's row order, with the names tables print."""
PAPER_DEFENSES = ("dagger", "gail", "dr", "dart", "aril")
"""The rows of the paper's Robust IL tables."""
BUNDLED_POLICIES = ("expert", *DEFENSES)
PER_MODE_POLICIES = ("dr", "aril")
"""Trained against one attack mode: one bundled file per env and mode."""
DEFAULT_POLICY = "dagger"
"""``bundled``: the paper's learner under attack."""
BUNDLED_NAMES = (*BUNDLED_POLICIES, "bundled")


class BundledFileError(ValueError):
    """A bundled name that has no file for this env (and mode)."""


def check_name(kind: str, name: str, names) -> str:
    """``name`` if it is one of ``names``, else a ValueError listing them."""
    if name not in names:
        raise ValueError(f"unknown {kind} {name!r}; choose one of {', '.join(names)}")
    return name


def user_data_dir() -> Path:
    """The user's data folder: ``$ARIL_DATA``, by default ``~/.local/share/aril_ros`` (read at each call)."""
    return Path(os.environ.get("ARIL_DATA") or Path.home() / ".local" / "share" / "aril_ros").expanduser()


def bundled_path(policy: str, env_id: str, mode: str | None = None, root: Path | None = None) -> Path:
    """Where the policy of that name lives under ``root`` (default: the package's data), whether or not it
    exists; ``dr`` and ``aril`` have one per mode."""
    root = DATA_DIR if root is None else root
    policy = DEFAULT_POLICY if policy == "bundled" else check_name("bundled policy", policy, BUNDLED_NAMES)
    if policy not in PER_MODE_POLICIES:
        return root / policy / f"{env_id}.pt"
    if mode not in ATTACKED_MODES:
        raise BundledFileError(f"the bundled {policy} policies are trained per attack mode: it takes mode sensory or "
                               f"physical (got {mode}); for another mode pass the file, e.g. "
                               f"{root / policy}/{env_id}-sensory.pt")
    return root / policy / f"{env_id}-{mode}.pt"


def user_path(policy: str, env_id: str, mode: str | None = None) -> Path:
    """Where a user's own file of that name goes (what the trainers write when given no ``out:=``)."""
    return bundled_path(policy, env_id, mode, user_data_dir())


def train_hint(policy: str, env_id: str, mode: str | None, out: Path) -> str:
    """The command that makes the file of a name at ``out`` (the expert's and BC's trainers write there by default)."""
    if policy in ("expert", "bc"):
        return f"aril train-{policy} env:={env_id}"
    if policy == "gail":
        return f"aril train-gail env:={env_id} out:={out}"
    return (f"aril train-learner algorithm:={policy} env:={env_id}"
            + (f" mode:={mode}" if policy in PER_MODE_POLICIES else "") + f" out:={out}")


def shadowed_by_bundled(policy: str, env_id: str, written: Path) -> str | None:
    """What to tell a user who wrote their own file of a name that a bundled file keeps (None if nothing is
    bundled by that name for that env): the name resolves to the bundled file first."""
    bundled = bundled_path(policy, env_id)
    if not bundled.is_file() or Path(written).resolve() == bundled:
        return None
    return (f"note: {env_id} has a bundled {policy}, which the name {policy} keeps meaning; use this one by its path "
            f"({policy if policy == 'expert' else 'policy'}:={written})")


def bundled_file(policy: str, env_id: str, mode: str | None = None) -> Path:
    """The file of a name: the bundled one, else the user's; when neither exists, an error saying where it
    looked, what is bundled, and how to make one or pass a file."""
    package, user = bundled_path(policy, env_id, mode), user_path(policy, env_id, mode)
    for path in (package, user):
        if path.is_file():
            return path
    kind = package.parent.name
    have = sorted({p.stem for folder in (package.parent, user.parent) for p in folder.glob("*.pt")})
    raise BundledFileError(f"no {kind} for {env_id}{f' ({mode})' if kind in PER_MODE_POLICIES else ''} "
                           f"(looked for {package} and {user}); there are: {', '.join(have) or 'none'}. "
                           f"Make one with `{train_hint(kind, env_id, mode, user)}`, or pass a policy file")


def for_task(name: str, env_id: str, mode: str | None = None) -> str:
    """``name`` as a task elsewhere must be given it: a bundled name whose file is the user's (``$ARIL_DATA``, an
    onboarded env's, which another node, or a task working in a folder of its own, does not have) becomes that file's
    path, to travel with the task; anything else stays as it is (a package file resolves in each node's own
    installation, and a name that resolves to nothing says so where it is used)."""
    if name not in BUNDLED_NAMES:
        return name
    try:
        path = bundled_file(name, env_id, mode)
    except BundledFileError:
        return name
    return name if path.is_relative_to(DATA_DIR) else str(path)


def adversary_path(env_id: str, mode: str, defense: str = DEFAULT_POLICY) -> Path:
    """Where the bundled ARIL-A trained against the bundled learner ``defense`` lives (whether or not
    it exists): the one against DAgger is ``attack:=aril_a``'s default."""
    if defense == DEFAULT_POLICY:
        return DATA_DIR / "adversary" / f"{env_id}-{mode}.pt"
    return DATA_DIR / "defense-adversary" / f"{env_id}-{mode}-{defense}.pt"


def directed_adversary_path(env_id: str, mode: str, defense: str = DEFAULT_POLICY) -> Path:
    """Where the bundled directed ARIL-A (``policy:=directed``) against the bundled learner ``defense`` lives (whether
    or not it exists): the one against DAgger is the attack tables' directed row; each is part of the verdict
    benchmark's reference for its learner, and a warm start of the scorecard's directed ARIL-A (their folder is
    :data:`aril_ros.verdict.DIRECTED_ZOO`, not the zoo's)."""
    if defense == DEFAULT_POLICY:
        return DATA_DIR / "directed-adversary" / f"{env_id}-{mode}.pt"
    return DATA_DIR / "directed-adversary" / f"{env_id}-{mode}-{defense}.pt"


def surrogate_path(env_id: str, mode: str) -> Path:
    """Where the bundled surrogate of the bundled DAgger learner lives (whether or not it exists): the attack tables'
    ``transfer`` row attacks it (``aril fit-surrogate`` makes one for any policy)."""
    return DATA_DIR / "surrogate" / f"{env_id}-{mode}.pt"


def user_calibration() -> Path:
    """The calibration ``aril calibrate-eps`` writes by default: the user's, beside their policies."""
    return user_data_dir() / CALIBRATION_NAME


def calibrated_eps(env_id: str, mode: str, calibration: str | Path | None = None) -> float:
    """The eps chosen for ``env_id`` and ``mode`` by ``aril calibrate-eps`` (the paper's 40% FGSM rule): from
    ``calibration``, or by default the bundled calibration, then the user's."""
    paths = [Path(calibration)] if calibration else [CALIBRATION, user_calibration()]
    for path in paths:
        if not path.is_file():
            continue
        for row in json.loads(path.read_text())["rows"]:
            if (row["env"], row["mode"]) == (env_id, mode):
                return float(row["chosen_eps"])
    looked = " and ".join(str(p) for p in paths)
    raise ValueError(f"no calibrated eps for {env_id} {mode} (looked in {looked}): pass eps:=<value>, or calibrate "
                     f"one against a learner of {env_id}: aril calibrate-eps envs:={env_id} modes:={mode} "
                     "policy:=<a learner: a bundled name or a file> (it needs an expert too: expert:=, or "
                     f"`aril train-expert env:={env_id}` first)")


@dataclass(frozen=True)
class AttackChoice:
    """The attack a run makes, its adversary file (aril_a; empty: the attack's own default), and why, when the
    caller named none."""

    name: str
    file: str = ""
    why: str = ""


def choose_attack(env_id: str, mode: str, policy: str, attack: str = "", attack_file: str = "") -> AttackChoice:
    """The attack of a run of ``policy`` (a bundled name, ``bundled``, a file or ``external``) in ``mode``: the one
    named, or, unnamed in an attacked mode, the strongest bundled for the policy: ARIL-A trained against it (the
    learned black-box adversary) where one is bundled, random noise where none is (the expert, a file of the user's,
    an external node)."""
    if attack or attack_file or mode == "clean":  # an adversary file alone names no attack: refused as before
        return AttackChoice(attack_for_mode(mode, attack), attack_file)
    check_name("mode", mode, MODES)
    learner = DEFAULT_POLICY if policy == "bundled" else policy
    adversary = adversary_path(env_id, mode, learner) if learner in DEFENSES else None
    if adversary is not None and adversary.is_file():
        return AttackChoice("aril_a", str(adversary), f"the default: the ARIL-A trained against {DEFENSES[learner]}, "
                                                      "bundled; attack:=random for noise")
    return AttackChoice("random", "", f"the default: no adversary is bundled against {policy} on {env_id} {mode}, "
                                      "so random noise; aril train-adversary victim:=<it> makes one (attack:=aril_a "
                                      "attack_file:=...), attack:=spsa queries it")


def attack_for_mode(mode: str, attack: str = "") -> str:
    """The attack a mode runs: ``attack``, or when unset none (clean) or random; clean runs no other (a run that
    knows its policy chooses with :func:`choose_attack`)."""
    check_name("mode", mode, MODES)
    name = check_name("attack", attack or ("none" if mode == "clean" else "random"), ATTACKS)
    if mode == "clean" and name != "none":
        raise ValueError(f"mode:=clean runs no attack, got attack:={name}")
    return name


MAX_EPS = 1.0
"""The largest eps an attack may be given: the top of ``aril calibrate-eps``'s sweep (the calibrated ones are
0.005-0.3). The zero-order entries are joint angles (rad) and heights (m); at pi the physical attack already
makes MuJoCo unstable (HalfCheetah, Swimmer), at 1.0 not yet."""


def attack_budget(env_id: str, mode: str, attack: str, eps: float) -> float:
    """The eps an attack runs with: ``eps`` when given (0 < eps <= :data:`MAX_EPS`); unset (0), the calibrated
    one for the env and mode, except for aril_a, whose adversary file carries its own (0 here lets it decide)."""
    if not (eps == 0 or 0 < eps <= MAX_EPS):  # NaN fails both
        raise ValueError(f"eps:={eps} is out of range: allowed 0 < eps <= {MAX_EPS} (joint angles in rad, heights "
                         f"in m; the top of aril calibrate-eps's sweep), or 0 for the calibrated one")
    if attack == "none":
        return 0.0
    if eps or attack == "aril_a":
        return eps
    return calibrated_eps(env_id, mode)
