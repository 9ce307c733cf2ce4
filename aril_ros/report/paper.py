"""The paper's figures (Tables 1 and 2, MuJoCo v2 envs), keyed like the report's rows."""

PAPER_ENV = {"HalfCheetah-v5": "HalfCheetah-v2", "Ant-v5": "Ant-v2", "Swimmer-v5": "Swimmer-v2"}
# The paper's Tables 1 and 2 (v2 envs): return and drop from its clean DAgger; rows it does not report are absent.
PAPER = {
    "sensory": {
        ("dagger", "none"): {"Ant-v5": (1245, 0.0), "HalfCheetah-v5": (3276, 0.0), "Swimmer-v5": (81, 0.0)},
        ("dagger", "fgsm"): {"Ant-v5": (945, -24.1), "HalfCheetah-v5": (2336, -28.7), "Swimmer-v5": (66, -18.5)},
        ("dagger", "fgsm_k"): {"Ant-v5": (884, -28.9), "HalfCheetah-v5": (1973, -39.8), "Swimmer-v5": (57, -29.6)},
        ("dagger", "aril_a"): {"Ant-v5": (607, -51.2), "HalfCheetah-v5": (830, -74.7), "Swimmer-v5": (38, -53.1)},
        ("gail", "worst"): {"Ant-v5": (638, -48.8), "HalfCheetah-v5": (1037, -68.3), "Swimmer-v5": (42, -48.1)},
        ("dr", "worst"): {"Ant-v5": (679, -45.5), "HalfCheetah-v5": (1372, -58.1), "Swimmer-v5": (56, -30.9)},
        ("dart", "worst"): {"Ant-v5": (779, -37.4), "HalfCheetah-v5": (1832, -44.1), "Swimmer-v5": (49, -39.5)},
        ("aril", "worst"): {"Ant-v5": (965, -22.5), "HalfCheetah-v5": (2974, -9.2), "Swimmer-v5": (72, -11.1)},
    },
    "physical": {
        ("dagger", "none"): {"Ant-v5": (1245, 0.0), "HalfCheetah-v5": (3276, 0.0), "Swimmer-v5": (81, 0.0)},
        ("dagger", "fgsm"): {"Ant-v5": (885, -28.9), "HalfCheetah-v5": (2100, -35.9), "Swimmer-v5": (61, -24.7)},
        ("dagger", "aril_a"): {"Ant-v5": (158, -87.3), "HalfCheetah-v5": (249, -92.5), "Swimmer-v5": (16, -80.2)},
        ("dart", "worst"): {"Ant-v5": (581, -53.3), "HalfCheetah-v5": (1078, -67.1), "Swimmer-v5": (27, -66.7)},
        ("aril", "worst"): {"Ant-v5": (903, -27.5), "HalfCheetah-v5": (2183, -33.4), "Swimmer-v5": (56, -30.1)},
    },
}
PAPER_OVERALL = {"sensory": {("dagger", "none"): 0.0, ("dagger", "fgsm"): -23.7, ("dagger", "fgsm_k"): -32.7,
                             ("dagger", "aril_a"): -59.7, ("gail", "worst"): -55.1, ("dr", "worst"): -44.8,
                             ("dart", "worst"): -40.3, ("aril", "worst"): -14.3},
                 "physical": {("dagger", "none"): 0.0, ("dagger", "fgsm"): -29.8, ("dagger", "aril_a"): -86.7,
                              ("dart", "worst"): -62.4, ("aril", "worst"): -30.3}}
TABLE_ROWS = (("dagger", "none"), ("dagger", "fgsm"), ("dagger", "fgsm_k"), ("dagger", "aril_a"),
              ("gail", "worst"), ("dr", "worst"), ("dart", "worst"), ("aril", "worst"))
