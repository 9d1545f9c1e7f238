"""Probing trained agents as a neuroscientist would (AngoraPy's `analysis/investigators`): record every layer's
activity with the task variables (`record_activity`, an xarray Dataset), decode variables from layers
(`decode`, ridge R^2 against a noise baseline) and lesion units (`lesion`)."""

from angora_jax.analysis.decoding import decode, plot_decoding
from angora_jax.analysis.lesion import dense_layers, lesion, lesion_fraction
from angora_jax.analysis.recording import record_activity, save_activity

__all__ = ["decode", "dense_layers", "lesion", "lesion_fraction", "plot_decoding", "record_activity",
           "save_activity"]
