"""Inverse problem support: parameter prior, tag-based stretching regression, datasets."""

from .._lazy import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "dataset": ("DatasetError", "generate", "load"),
    "prior": ("LATENT_NAMES", "STRETCH_PRIOR", "FabricPrior", "PriorError", "default_prior"),
    "tags": ("Catalogue", "StretchKNN", "TagError", "TagVocab", "encode_tag", "load_catalogue", "save_catalogue",
             "synthetic_catalogue"),
}, globals())
"""Names imported on first use (``drapejax._lazy``), so that ``inverse.estimate`` does not load the dataset
generator's solver."""
