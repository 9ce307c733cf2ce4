"""The paper's figures (Tables 1 and 2, MuJoCo v2 envs), keyed like the report's rows."""
from ..registry import DIRECTED_ROW, PAPER_ENVS, SEARCH_ROW


def _per_env(*figures) -> dict:
    """Figures given in the order of ``registry.PAPER_ENVS`` (HalfCheetah, Ant, Swimmer), keyed by our env ids."""
    return dict(zip(PAPER_ENVS, figures))


PAPER_ENV = _per_env("HalfCheetah-v2", "Ant-v2", "Swimmer-v2")
"""The env each of ours stands in for."""
PAPER_OBS_DIM = _per_env(17, 111, 8)
"""Observation sizes of the paper's -v2 envs."""
BLACK_BOX_ROWS = ("transfer", SEARCH_ROW, DIRECTED_ROW)
"""Attacks on DAgger beyond the paper's: the black-box verdict pipeline's strongest (issue 38), FGSM^k on a surrogate
fitted to DAgger's answers and ARIL-A with query-time search, and the directed ARIL-A (PA-AD's director and actor,
black-box). DAgger alone meets them: a defense's worst case stays the worst of ``registry.THREATS``, as the
paper's."""
TABLE_ROWS = (("dagger", "none"), ("dagger", "fgsm"), ("dagger", "fgsm_k"), ("dagger", "aril_a"),
              *(("dagger", attack) for attack in BLACK_BOX_ROWS),
              ("gail", "worst"), ("dr", "worst"), ("dart", "worst"), ("aril", "worst"))
"""The rows of the paper's Tables 1 and 2: DAgger clean and under each attack (Adversary; the paper's three, then
:data:`BLACK_BOX_ROWS`), then each defense under its worst attack (Robust IL)."""
# The paper's Tables 1 and 2 (v2 envs): return and drop from its clean DAgger; rows it does not report are absent.
PAPER = {
    "sensory": {
        ("dagger", "none"): _per_env((3276, 0.0), (1245, 0.0), (81, 0.0)),
        ("dagger", "fgsm"): _per_env((2336, -28.7), (945, -24.1), (66, -18.5)),
        ("dagger", "fgsm_k"): _per_env((1973, -39.8), (884, -28.9), (57, -29.6)),
        ("dagger", "aril_a"): _per_env((830, -74.7), (607, -51.2), (38, -53.1)),
        ("gail", "worst"): _per_env((1037, -68.3), (638, -48.8), (42, -48.1)),
        ("dr", "worst"): _per_env((1372, -58.1), (679, -45.5), (56, -30.9)),
        ("dart", "worst"): _per_env((1832, -44.1), (779, -37.4), (49, -39.5)),
        ("aril", "worst"): _per_env((2974, -9.2), (965, -22.5), (72, -11.1)),
    },
    "physical": {
        ("dagger", "none"): _per_env((3276, 0.0), (1245, 0.0), (81, 0.0)),
        ("dagger", "fgsm"): _per_env((2100, -35.9), (885, -28.9), (61, -24.7)),
        ("dagger", "aril_a"): _per_env((249, -92.5), (158, -87.3), (16, -80.2)),
        ("dart", "worst"): _per_env((1078, -67.1), (581, -53.3), (27, -66.7)),
        ("aril", "worst"): _per_env((2183, -33.4), (903, -27.5), (56, -30.1)),
    },
}
PAPER_CLEAN = {env: figure[0] for env, figure in PAPER["sensory"][("dagger", "none")].items()}
"""The paper's clean DAgger return per env (the reference of its drops)."""
PAPER_OVERALL = {"sensory": {("dagger", "none"): 0.0, ("dagger", "fgsm"): -23.7, ("dagger", "fgsm_k"): -32.7,
                             ("dagger", "aril_a"): -59.7, ("gail", "worst"): -55.1, ("dr", "worst"): -44.8,
                             ("dart", "worst"): -40.3, ("aril", "worst"): -14.3},
                 "physical": {("dagger", "none"): 0.0, ("dagger", "fgsm"): -29.8, ("dagger", "aril_a"): -86.7,
                              ("dart", "worst"): -62.4, ("aril", "worst"): -30.3}}
