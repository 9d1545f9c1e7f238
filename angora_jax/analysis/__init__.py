"""Probing trained agents as a neuroscientist would (AngoraPy's `analysis/investigators`).

Record every layer's activity with the task variables (`record_activity`, an xarray Dataset), then: decode variables
from layers (`decode`, ridge R^2 against a noise baseline), compare representations (`similarity`, RSA with rsatoolbox),
reduce dimensionality and find fixed points (`principal_components`, `agent_fixed_points`, with a graph area's input
from `area_input`), measure intrinsic timescales (`timescales`), which layer leads which (`cross_correlation`), what a
layer tells of the future (`decode(..., lags=...)`), tuning (`tuning_curves`), the equations of a layer's dynamics in
its leading principal components and how well they predict held-out episodes (`sindy`, with pysindy), and lesion units,
areas, input modalities or action components (a muscle: `silence_actions`) and measure the task outcome (`ablation`); of
a muscle-driven hand, the muscle synergies (`synergies`, NMF) and whether each area reads out more like the muscles or
the movements (`muscles_or_movements`, against the random-weights control); inside the visual area of an agent that sees
camera images or of a cube pose estimator, first-layer filters, feature maps, gradient saliency and preferred stimuli
(`visual_analysis`), the saliency of the pose an estimator reads (`pose_saliency`) and its share on the cube
(`saliency_share`). Each analysis has a `plot_*` and an `angora-jax analyze` verb. What to probe of the brain-area model
on each hand task (its areas, the variables to decode, the lesions and the outcomes that measure them) is in `PROBES`
(task name -> `Probe`; the lesions from `reach_lesions`, `cube_lesions` and `muscle_lesions`).
"""

from angora_jax.analysis.decoding import decode, plot_decoding
from angora_jax.analysis.dynamics import (
    agent_fixed_points,
    area_input,
    find_fixed_points,
    plot_dynamics,
    principal_components,
)
from angora_jax.analysis.equations import fit_sindy, plot_sindy, sindy
from angora_jax.analysis.lesion import (
    ablation,
    dense_layers,
    lesion,
    lesion_area,
    lesion_fraction,
    plot_ablation,
    silence_actions,
    silence_modality,
    with_random_weights,
)
from angora_jax.analysis.muscles import muscles_or_movements, plot_muscles_or_movements
from angora_jax.analysis.probes import PROBES, Probe, cube_lesions, muscle_lesions, reach_lesions
from angora_jax.analysis.recording import episode_outcomes, record_activity, replay_activity, save_activity
from angora_jax.analysis.similarity import plot_similarity, similarity
from angora_jax.analysis.synergies import plot_synergies, synergies
from angora_jax.analysis.timescales import cross_correlation, plot_cross_correlation, plot_timescales, timescales
from angora_jax.analysis.tuning import plot_tuning, tuning_curves
from angora_jax.analysis.visual import (
    feature_maps,
    first_layer_filters,
    gradient_saliency,
    mask_edges,
    plot_visual,
    pose_saliency,
    preferred_stimuli,
    saliency,
    saliency_share,
    visual_analysis,
)

__all__ = ["PROBES", "Probe", "ablation", "agent_fixed_points", "area_input", "cross_correlation", "cube_lesions",
           "decode", "dense_layers", "episode_outcomes", "feature_maps", "find_fixed_points", "first_layer_filters",
           "fit_sindy", "gradient_saliency", "lesion", "lesion_area", "lesion_fraction", "mask_edges", "muscle_lesions",
           "muscles_or_movements", "plot_ablation", "plot_cross_correlation", "plot_decoding", "plot_dynamics",
           "plot_muscles_or_movements", "plot_similarity", "plot_sindy", "plot_synergies", "plot_timescales",
           "plot_tuning", "plot_visual", "pose_saliency", "preferred_stimuli", "principal_components", "reach_lesions",
           "record_activity", "replay_activity", "saliency", "saliency_share", "save_activity", "silence_actions",
           "silence_modality", "similarity", "sindy", "synergies", "timescales", "tuning_curves", "visual_analysis",
           "with_random_weights"]
