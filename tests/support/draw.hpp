#pragma once
// Random draws in the order they are written. C++ leaves the order in which a call's
// arguments are evaluated unspecified (GCC evaluates them right to left on x86-64, left to
// right on aarch64), so `Eigen::Vector3d(u(rng), u(rng), z(rng))` is another sample on
// another compiler or architecture, and a test that passes on one may not on the other.
// A braced list is evaluated left to right everywhere.
#include <Eigen/Core>

namespace markcell::test {

// draw(rng, a, b, c) = (a(rng), b(rng), c(rng)), drawn in that order.
template <class Rng, class... Dist>
Eigen::Matrix<double, sizeof...(Dist), 1> draw(Rng& rng, Dist&... dist) {
  const double values[] = {static_cast<double>(dist(rng))...};
  return Eigen::Map<const Eigen::Matrix<double, sizeof...(Dist), 1>>(values);
}

}  // namespace markcell::test
