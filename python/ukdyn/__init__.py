"""ukdyn: Udwadia-Kalaba dynamics of constrained multibody systems, from Python.

    import ukdyn
    sc = ukdyn.load_scenario("scenarios/paper.yaml")
    r = sc.forward(0.0, sc.q0, sc.qd0)          # M, Q, A, b, Qc, qdd, rank, residual
    run = sc.simulate(controller=lambda t, q, qd: -10 * qd)
    run["theta1"]                                # a numpy view of the C++ result (no copy)

Errors from ukdyn are ukdyn.Error (ukdyn.ScenarioError for a bad scenario file, with its
FILE:LINE:COLUMN: key '...': message). The tutorial is docs/python.md.
"""

from ._ukdyn import (
    AppliedForce,
    Constraint,
    ConstraintDef,
    ControlData,
    Data,
    DefinitionError,
    Error,
    ForceDef,
    ForwardResult,
    Linearization,
    Optimized,
    Run,
    Scenario,
    ScenarioError,
    StructuredDerivatives,
    Subsystem,
    SubsystemDef,
    System,
    __version__,
    make_applied_force,
    make_constraint,
    make_subsystem,
    ipopt_available,
)
from ._ukdyn import optimize as _optimize
from ._ukdyn import size as _size


def load_scenario(path, check_initial=True):
    """Loads and validates a scenario file (docs/scenario-format.md); same as Scenario.load."""
    return Scenario.load(str(path), check_initial)


def optimize(path, out=None):
    """Solves a trajectory-optimisation problem file (docs/optimization.md) by collocation on IPOPT;
    with out, also writes the run folder (trajectory.csv, summary.json) and runs the open-loop
    replay check. Returns an Optimized (t, q, qd, qdd, u, Qc, mu as numpy arrays; cost, status,
    trusted, message, ...). Raises ukdyn.ScenarioError for a bad problem file."""
    return _optimize(str(path), None if out is None else str(out))


def size(path, out=None):
    """Sizes the actuators of a sizing file (docs/sizing.md): per actuator the smallest catalogue
    motor + gearbox that keeps the margin at every operating point of every sample, each candidate
    re-run with its motor in the model. Returns sizing.json as a dict; with out, also writes
    sizing.json and candidates.csv there. Raises ukdyn.ScenarioError for a bad file."""
    return _size(str(path), None if out is None else str(out))


__all__ = [
    "AppliedForce",
    "Constraint",
    "ConstraintDef",
    "ControlData",
    "Data",
    "DefinitionError",
    "Error",
    "ForceDef",
    "ForwardResult",
    "Linearization",
    "Optimized",
    "Run",
    "Scenario",
    "ScenarioError",
    "StructuredDerivatives",
    "Subsystem",
    "SubsystemDef",
    "System",
    "__version__",
    "load_scenario",
    "ipopt_available",
    "optimize",
    "size",
    "make_applied_force",
    "make_constraint",
    "make_subsystem",
]
