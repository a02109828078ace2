"""Inverse problem support: parameter prior, tag-based stretching regression, datasets."""

import importlib

_EXPORTS = {
    "dataset": ("DatasetError", "generate", "load"),
    "prior": ("LATENT_NAMES", "STRETCH_PRIOR", "FabricPrior", "PriorError", "default_prior"),
    "tags": ("Catalogue", "StretchKNN", "TagError", "TagVocab", "encode_tag", "load_catalogue", "save_catalogue",
             "synthetic_catalogue"),
}
"""Where each name lives; imported on first use (PEP 562), so that ``inverse.estimate`` does not load the
dataset generator's solver."""

_HOME = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = list(_HOME)


def __getattr__(name: str):
    if name in _HOME:
        value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
        globals()[name] = value
        return value
    try:
        return importlib.import_module(f".{name}", __name__)
    except ModuleNotFoundError as e:
        if e.name != f"{__name__}.{name}":
            raise
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
