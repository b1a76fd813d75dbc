"""Stand-ins for modules that the official DUSt3R / Spann3R code imports but
Debian 12 lacks, for the golden-case scripts (golden_official.py,
golden_linear_head.py) whose forward passes do not use them: huggingface_hub
(the hub-loading base class), packaging (dust3r's version assert) and einops.
"""
import sys
import types


def install(rearrange=None):
    """Registers the stand-ins where the real modules are missing. einops:
    with `rearrange` given, that function replaces einops.rearrange even where
    einops is installed (the caller needs its exact numerics); without, an
    einops whose functions refuse to run stands in where it is missing."""
    hub = types.ModuleType("huggingface_hub")
    hub.__version__ = "0.22.0"

    class PyTorchModelHubMixin:
        def __init_subclass__(cls, **kwargs):
            super().__init_subclass__()
    hub.PyTorchModelHubMixin = PyTorchModelHubMixin
    version = types.ModuleType("packaging.version")
    version.parse = lambda s: tuple(int(x) for x in s.split(".")[:3])
    packaging = types.ModuleType("packaging")
    packaging.version = version
    for name, mod in [("huggingface_hub", hub), ("packaging", packaging),
                      ("packaging.version", version)]:
        sys.modules.setdefault(name, mod)

    def unused(*args, **kwargs):
        raise RuntimeError("einops stand-in: not used by these forward passes")
    einops = types.ModuleType("einops")
    einops.rearrange, einops.repeat = rearrange or unused, unused
    if rearrange is not None:
        sys.modules["einops"] = einops
    else:
        sys.modules.setdefault("einops", einops)
