"""``aril render``: see an attack. One episode per panel, rendered offscreen on the CPU and placed side
by side in an animated GIF: by default the DAgger learner clean, the DAgger learner under the ARIL-A
trained against it, and the ARIL learner under the ARIL-A trained against *it*.

    aril render env:=HalfCheetah-v5 mode:=physical out:=docs/results/attack-HalfCheetah-v5-physical.gif

MuJoCo draws with Mesa's EGL (``MUJOCO_GL=egl``, Debian's ``libegl-mesa0``: in the base image) unless
``MUJOCO_GL`` says otherwise (``osmesa`` needs ``apt-get install libosmesa6``). mujoco picks its GL
backend when it is imported, so each panel renders in a spawned process that sets ``MUJOCO_GL`` first;
rendering is opt-in and never touches the ordinary runs. Each frame is labelled with the policy, the
attack and the return so far.
"""
from __future__ import annotations

import multiprocessing
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .args import arg
from .registry import ATTACKS, DEFAULT_ENV, MAX_EPS

class RenderError(RuntimeError):
    """No offscreen GL backend: says which Debian packages give one."""


def frame_size(text: str) -> tuple[int, int]:
    """``(width, height)`` of a ``<width>x<height>`` frame size such as ``320x240``."""
    width, x, height = text.lower().partition("x")
    if not (x and width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
        raise ValueError(f"render_size:={text} is not a frame size: <width>x<height> in pixels, e.g. 320x240")
    return int(width), int(height)


GL_HELP = ("offscreen rendering failed: MuJoCo needs Mesa's EGL (apt-get install libegl-mesa0 libgl1-mesa-dri) "
           "or, with MUJOCO_GL=osmesa, OSMesa (apt-get install libosmesa6)")


@dataclass
class RenderConfig:
    """Arguments of ``aril render``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "sensory or physical (the attacked panels)")
    panels: str = arg("dagger:none,dagger:aril_a,aril:aril_a",
                      "comma-separated policy:attack panels; policy is a bundled name (aril and dr: the one of "
                      f"mode:=), attack one of {', '.join(ATTACKS)} (aril_a: the bundled ARIL-A trained against "
                      "that bundled policy)")
    eps: float = arg(0.0, "attack budget (0: the calibrated one for env and mode)", low=0.0, high=MAX_EPS)
    steps: int = arg(300, "control steps of the episode", low=1, high=100_000)
    every: int = arg(3, "render every this many control steps", low=1, high=1000)
    fps: int = arg(20, "frames per second of the GIF", low=1, high=100)
    width: int = arg(320, "panel width in pixels", low=16, high=4096)
    height: int = arg(240, "panel height in pixels", low=16, high=4096)
    seed: int = arg(0, "env seed of the episode (and of the attack noise)", low=0, high=2**31 - 1)
    out: str = arg("", "the GIF (default runs/render-<env>-<mode>.gif)")


class FrameRenderer:
    """Offscreen RGB frames of a :class:`~aril_ros.envs.MujocoSim` from a camera tracking the root body.
    ``MUJOCO_GL`` must be set (``egl``/``osmesa``) before mujoco is first imported in the process."""

    def __init__(self, sim, width: int, height: int):
        import mujoco

        self.sim = sim
        try:
            self.renderer = mujoco.Renderer(sim.model, height, width)
        except Exception as err:  # the GL backends raise their own types
            raise RenderError(f"{GL_HELP} ({type(err).__name__}: {err}; MUJOCO_GL="
                              f"{os.environ.get('MUJOCO_GL', 'unset')})") from None
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        self.camera.trackbodyid = 1  # the root body: the robot stays in frame as it runs
        self.camera.distance = 3.5  # about gymnasium's default camera (its model extent counts the floor)
        self.camera.elevation = -20.0

    def rgb(self) -> np.ndarray:
        self.renderer.update_scene(self.sim.data, self.camera)
        return self.renderer.render()

    def jpeg(self, quality: int = 80) -> bytes:
        import io

        from PIL import Image

        buffer = io.BytesIO()
        Image.fromarray(self.rgb()).save(buffer, "JPEG", quality=quality)
        return buffer.getvalue()

    def close(self) -> None:
        self.renderer.close()


def _panel_frames(cfg: RenderConfig, policy_name: str, attack_name: str) -> tuple[list[np.ndarray], float]:
    """One panel's labelled frames and its return; runs in a process whose MUJOCO_GL is already set."""
    from PIL import Image, ImageDraw

    from .attacks import make_attack
    from .envs import layout_of
    from .policy import resolve_policy
    from .registry import adversary_path, attack_budget
    from .rollout import RolloutEngine

    layout = layout_of(cfg.env)
    mode = "clean" if attack_name == "none" else cfg.mode
    policy = resolve_policy(policy_name, cfg.env, cfg.mode)
    expert = resolve_policy("expert", cfg.env)
    adversary = str(adversary_path(cfg.env, cfg.mode, policy_name)) if attack_name == "aril_a" else None
    attack = make_attack(attack_name, layout, attack_budget(cfg.env, mode, attack_name, cfg.eps), victim=policy,
                         expert=expert, adversary=adversary, mode=mode)
    engine = RolloutEngine(cfg.env, policy, expert, attack, mode, 1, cfg.steps)
    sim = engine.sims.sims[0]
    renderer = FrameRenderer(sim, cfg.width, cfg.height)
    label = f"{policy_name}, {'clean' if attack_name == 'none' else f'{attack_name} eps {attack.eps:g}'}"
    frames, total = [], 0.0
    for step in engine.iter_steps(1, cfg.seed):
        total += float(step.reward[0])
        if step.t % cfg.every == 0 or step.done[0]:
            image = Image.fromarray(renderer.rgb())
            draw = ImageDraw.Draw(image)
            draw.rectangle((0, 0, cfg.width, 32), fill=(0, 0, 0))  # the labels stay legible on any floor
            draw.text((6, 4), label, fill=(255, 255, 255))
            draw.text((6, 18), f"t {step.t + 1:4d}  return {total:8.1f}", fill=(255, 255, 255))
            frames.append(np.asarray(image))
    renderer.close()
    engine.close()
    return frames, total


def _spawned_panel(args):
    cfg, policy_name, attack_name = args
    return _panel_frames(cfg, policy_name, attack_name)


def render(cfg: RenderConfig, log=print) -> Path:
    """Render the panels (two at a time) and write them side by side as a GIF; returns its path."""
    from PIL import Image

    panels = [tuple(p.split(":", 1)) for p in cfg.panels.split(",") if p.strip()]
    bad = [":".join(p) for p in panels if len(p) != 2]
    if bad or not panels:
        raise ValueError(f"panels:= takes policy:attack entries, got {cfg.panels!r}")
    if cfg.every < 1 or cfg.steps < 1:
        raise ValueError("steps:= and every:= must be at least 1")
    out = Path(cfg.out or f"runs/render-{cfg.env}-{cfg.mode}.gif")
    if out.suffix.lower() != ".gif":
        raise ValueError(f"out:= must end in .gif, got {out}")
    os.environ.setdefault("MUJOCO_GL", "egl")  # read by the spawned panels when they import mujoco
    with multiprocessing.get_context("spawn").Pool(min(2, len(panels))) as pool:
        results = pool.map(_spawned_panel, [(cfg, p, a) for p, a in panels])
    length = max(len(frames) for frames, _ in results)
    # a panel whose episode ended early (Ant falls) holds its last frame
    strips = [np.concatenate([frames[min(i, len(frames) - 1)] for frames, _ in results], axis=1)
              for i in range(length)]
    out.parent.mkdir(parents=True, exist_ok=True)
    # 64 colours, no dithering: a tracking camera over a checkered floor changes every pixel each frame
    images = [Image.fromarray(s).quantize(colors=64, dither=Image.Dither.NONE) for s in strips]
    images[0].save(out, save_all=True, append_images=images[1:], duration=int(1000 / cfg.fps), loop=0,
                   optimize=True)
    for (policy_name, attack_name), (_, total) in zip(panels, results):
        log(f"[render {cfg.env} {cfg.mode}] {policy_name} / {attack_name}: return {total:.1f} over {cfg.steps} steps")
    log(f"[render] {len(images)} frames of {len(panels)} panels -> {out}")
    return out
