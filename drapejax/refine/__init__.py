"""Gradient refinement of fabric parameters through the simulator (issue 5).

Fitted vector θ (log space): ``log k1`` along warp, weft and bias (k2 scaled with k1, i.e.
the k2/k1 ratio of the initial estimate is kept), followed by the parameters of caller-given
effects. When the areal density is unknown the drape depends on k/ρ only, so ρ is held at its
initial (nominal) value and k/ρ is reported.

Residuals are PHASE-INVARIANT because fold placement is random from drop to drop: the drape
coefficient, the amplitudes of the rim-profile harmonics 1..12 (|FFT| discards the fold phase,
so a rotated or mirrored fold pattern costs nothing and neither the in-plane rotation nor an
unknown warp angle has to be optimised), and, when a height map or scan exists, the mean hem
height. Amplitudes cannot tell warp from weft (a 90° turn swaps them), so when the warp angle is
known one phase-dependent term is added: the second-harmonic component along the warp
(``warp_anisotropy``), a material property rather than a fold placement; when it is unknown, warp
is by convention the stiffer direction of the initial estimate. Terms that the base model keeps
at zero by symmetry are fitted too, so that effects added to the model (``drapejax.effects``)
have something to explain: the world-frame first harmonic (off-centre), the bias shear
(unequal bias rigidities, when the warp angle is known) and, with heights, the mean height on
two rings (the hanging profile's shape). Each is whitened by its re-drop noise floor (DC 0.035,
2 mm per harmonic ≈ 6.2 mm spectral distance over 12 harmonics, 5 mm hem height). A Gaussian
prior in log space around the initial estimate keeps weakly identified directions in place.
Stretching is not fitted (weakly identifiable from a drape): it stays at the tag/prior estimate
of the initial guess.

Values are the HARD observables of the rest mesh (spec-exact renderer, as used for the
measurement); gradients are those of soft surrogates (soft rim profile, vertex hem heights):
``f = soft + stop_gradient(hard - soft)``, so the fit targets exactly what is evaluated while
gradients exist. The rest state is found by a warm-started ``static_solve`` on the host side and
differentiated by ``equilibrium`` (implicit function theorem), never by unrolling.

The optimiser is a Levenberg–Marquardt loop on the whitened residuals written in Python around
jitted (residual, Jacobian) evaluations, because every evaluation warm-starts the forward solve
from the previous accepted rest state (a host-side cache optimistix' pure loop cannot hold);
the damped normal equations are solved with ``lineax``. Uncertainty is the Laplace
(Gauss–Newton) covariance ``(JᵀJ + P)⁻¹`` of θ at the end point.

The package splits this by job: ``observables`` (measured targets, rest-state features and their
soft surrogates), ``misfit`` (the noise-whitened residuals), ``problem`` (θ, the prior, rest
states and the Jacobian), ``lm`` (the Levenberg–Marquardt loop and ``fit``), ``uncertainty``
(Laplace covariance, what the drape identified), ``meshing`` (the fit mesh and its limits),
``presets`` (the solvers), ``converged`` (the fit continued on nested meshes down to a converged
resolution), ``context`` (``FitContext``: the settings a fit and every refit built
on it share), ``tensile`` (the membrane a strip tensile test implies, which every fit then
holds) and ``pipeline`` (``estimate``, the network start refined). Every name is importable
from ``drapejax.refine`` itself.
"""

from __future__ import annotations

from .._lazy import lazy_exports

_names, __getattr__, __dir__ = lazy_exports(__name__, {
    ".material": ("DIRECTIONS",),
    "context": ("FitContext",),
    "converged": ("CONVERGED_SPACING_M", "converged_hierarchy", "converged_refit"),
    "errors": ("RefineError",),
    "lm": ("LAPLACE_STATUSES", "FitResult", "fit", "run_lm", "_lm_step"),
    "meshing": ("FIT_RIM_SPACING_M", "FIT_SPACING_M", "MIN_BENDING_LENGTH_BUCKLING_M", "MIN_BENDING_LENGTH_M",
                "bending_length_m", "fit_mesh", "mesh_warnings"),
    "misfit": ("SIGMA_C1_M", "SIGMA_DC", "SIGMA_H2_M", "SIGMA_HARMONIC_M", "SIGMA_HEIGHT_C1_M", "SIGMA_HEM_M",
               "SIGMA_PROFILE_M", "Misfit"),
    "observables": ("EXTENT_M", "N_ANGLES", "N_HARMONICS", "PROFILE_RADII_M", "RING_HALF_WIDTH_M", "RING_RADII_M",
                    "Targets", "bias_shear", "first_harmonic", "fold_rms", "hard_features", "height_first_harmonic",
                    "measured_targets", "ring_heights", "warp_anisotropy", "_F", "_sil_from", "_soft_features"),
    "pipeline": ("compare", "estimate", "reported_params", "to_fabric", "_initial_guess"),
    "presets": ("CONTINUATION_CONFIG", "EXACT_CONFIG", "SOLVERS"),
    "tensile": ("measured_membrane_std", "membrane_from_tensile", "membrane_of_captures", "tensile_force"),
    "problem": ("K_PRIOR_STD", "Effect", "Problem", "prepare_programs", "prior_sqrt_information", "_problem_functions"),
    "uncertainty": ("best_combination", "identified", "laplace_cov"),
}, globals())
"""Names are imported on first use (``drapejax._lazy``), so that ``drapejax.refine.tensile`` (which
``estimate --no-refine`` reads strip readings with) does not load the solver and optimiser. The
underscored names are private helpers kept reachable as ``refine._name`` for ``diagnose`` and the
tests; they stay out of ``__all__`` (the experiments use public names only)."""

__all__ = [n for n in _names if not n.startswith("_")]
