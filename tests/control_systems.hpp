// The small systems of tests/test_control.cpp: a point mass on a rod of length 1 (the physical
// constraint) whose angle must follow θr(t) = 0.3 (1 − cos 2t) (the servo row
// x cos θr + z sin θr = sin(θ − θr) = 0), pushed by a horizontal force u (actuator fx).
// Also the base scenario and plant of the sweep file fuzzer (fuzz/fuzz_sweep.cpp).
#pragma once

#include <string>

namespace uktest {

/// The scenario text: the bob's mass, its `simulation:` mapping, then `extra` (a control section,
/// say) appended.
inline std::string pendulum_servo_yaml(
    double mass = 1.0, const std::string& extra = "",
    const std::string& simulation = "{t_end: 4, sample_dt: 0.01, abs_tol: 1e-13, rel_tol: 1e-13}") {
  return R"(ukdyn: 1
name: pendulum_servo
gravity: 9.8
subsystems:
  - name: bob
    type: definitions
    coordinates: [x, z]
    parameters: {m: )" +
         std::to_string(mass) + R"(}
    bodies:
      - {name: bob, mass: m, com: [x, 0, z]}
constraints:
  - type: expression
    name: rod
    rows: {circle: (x^2 + z^2 - 1)/2}
  - type: expression
    name: swing
    let: {th: 0.3*(1 - cos(2*t))}
    rows: {angle: x*cos(th) + z*sin(th)}
actuators:
  - {name: fx, coordinate: x}
initial:
  q: [0, -1]
simulation: )" +
         simulation + "\n" + extra;
}

}  // namespace uktest
