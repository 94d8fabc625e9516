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
    Run,
    Scenario,
    ScenarioError,
    Subsystem,
    SubsystemDef,
    System,
    __version__,
    make_applied_force,
    make_constraint,
    make_subsystem,
)


def load_scenario(path, check_initial=True):
    """Loads and validates a scenario file (docs/scenario-format.md); same as Scenario.load."""
    return Scenario.load(str(path), check_initial)


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
    "Run",
    "Scenario",
    "ScenarioError",
    "Subsystem",
    "SubsystemDef",
    "System",
    "__version__",
    "load_scenario",
    "make_applied_force",
    "make_constraint",
    "make_subsystem",
]
