"""Inverse problem support: parameter prior, tag-based stretching regression, datasets."""

from .dataset import DatasetError, generate, load
from .prior import LATENT_NAMES, STRETCH_PRIOR, FabricPrior, PriorError, default_prior
from .tags import (Catalogue, StretchKNN, TagError, TagVocab, encode_tag, load_catalogue,
                   save_catalogue, synthetic_catalogue)

__all__ = ["FabricPrior", "PriorError", "default_prior", "LATENT_NAMES", "STRETCH_PRIOR",
           "Catalogue", "StretchKNN", "TagError", "TagVocab", "encode_tag", "load_catalogue",
           "save_catalogue", "synthetic_catalogue", "DatasetError", "generate", "load"]
