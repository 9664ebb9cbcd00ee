// Unit constants: the SI value of one unit, so that `length_mm * kMm` is metres and
// `angle / kDeg` is degrees. Files and messages carry units in key names (length_mm, angle_deg);
// the engine works in SI. Include this where values cross that boundary (core.h does not).
#pragma once

#include <numbers>

namespace vcsim {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kMm = 1e-3;            // m
inline constexpr double kUm = 1e-6;            // m
inline constexpr double kInch = 25.4e-3;       // m
inline constexpr double kFrench = 1e-3 / 3.0;  // m of outer diameter: 1 Fr = 1/3 mm
inline constexpr double kDeg = kPi / 180.0;    // rad
inline constexpr double kDegPerRad = 180.0 / kPi;
inline constexpr double kMl = 1e-6;        // m^3
inline constexpr double kAtm = 101325.0;  // Pa (standard atmosphere; balloon gauges read atm)

}  // namespace vcsim
