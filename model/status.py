"""Status codes the compiled drivers return (one definition for every plate model and solver)."""

from __future__ import annotations

#: The run reached its last sample.
RUN_OK = 0
#: A sample, the energy balance or the error estimate became NaN or infinite.
RUN_NONFINITE = 1
#: dopri5 attempted more steps than its budget allows.
RUN_STEP_BUDGET = 2
#: dopri5's step fell below 1e-14 of the duration.
RUN_STEP_TOO_SMALL = 3
#: The Green's-function plate got a response shorter than the run.
RUN_SHORT_RESPONSE = 4
