import pytest
from PIL import Image

from aril_ros.render import RenderConfig, render


@pytest.mark.slow
def test_panels_are_rendered_side_by_side_into_a_gif(tmp_path):
    out = render(RenderConfig(env="Swimmer-v5", mode="physical", panels="dagger:none,aril:aril_a", steps=7, every=3,
                              width=64, height=48, out=str(tmp_path / "a.gif")), log=lambda *a, **k: None)
    gif = Image.open(out)
    assert gif.size == (2 * 64, 48) and gif.n_frames == 3  # steps 1, 4, 7
    frames = []
    for i in range(gif.n_frames):
        gif.seek(i)
        frames.append(gif.convert("RGB").tobytes())
    assert len(set(frames)) == 3  # the swimmer moves


def test_bad_render_arguments_are_refused(tmp_path):
    with pytest.raises(ValueError, match="policy:attack"):
        render(RenderConfig(panels="dagger"), log=lambda *a, **k: None)
    with pytest.raises(ValueError, match=r"\.gif"):
        render(RenderConfig(env="Swimmer-v5", steps=1, width=32, height=24, panels="dagger:none",
                            out=str(tmp_path / "a.mp4")), log=lambda *a, **k: None)
