"""odocompass estimator: pure JAX functions, float64 (SPEC §6).

Requires 64-bit JAX: ``jax.config.update("jax_enable_x64", True)`` in an application, or
``with jax.enable_x64(True):`` around calls where the host's global setting must stay as it
is (the FMU does this).  ``make_params`` refuses to build float32 parameters.
"""

from .model import (DEFAULT_CONFIG, MODES, Config, Inputs, Outputs, State, init_state, make_inputs, run,
                    run_batch, run_from, step)
from .params import (DPP_KEYS, PARAMETER_KEYS, PARAMETER_SPECS, PARAMETER_TABLE, UNIDENTIFIED_VEHICLE,
                     UNKNOWN_VELOCITY_COEFFICIENT, VEHICLE_KEYS, ParameterError, Params, for_unidentified_vehicle,
                     load_params, make_params, params_to_dict, save_params, validate_params)

__all__ = [
    "Config", "DEFAULT_CONFIG", "MODES", "Inputs", "Outputs", "State", "Params", "ParameterError",
    "PARAMETER_KEYS", "PARAMETER_SPECS", "PARAMETER_TABLE", "init_state", "make_inputs", "make_params",
    "load_params", "save_params", "params_to_dict", "validate_params", "run", "run_batch", "run_from", "step",
    "VEHICLE_KEYS", "DPP_KEYS", "UNIDENTIFIED_VEHICLE", "UNKNOWN_VELOCITY_COEFFICIENT", "for_unidentified_vehicle",
]
