#include "markcell/rig/line_motion.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>

#include "markcell/common/splitmix.hpp"

namespace markcell::rig {

LineMotion::LineMotion(const SpeedProfile& speed, const LinePath& path, Nanos duration)
    : path_(path), duration_(duration) {
  if (duration <= 0) throw std::invalid_argument("line motion: duration must be positive");
  if (speed.min_speed < 0 || speed.max_speed < speed.min_speed)
    throw std::invalid_argument("line motion: need 0 <= min_speed <= max_speed");
  const auto steps = static_cast<std::size_t>(duration / kNanosPerMilli) + 1;
  distance_.resize(steps + 1);
  speed_.resize(steps + 1);
  // Fluctuation: a sum of four slow sines with seeded frequencies and phases, scaled so
  // it can never leave the band.
  SplitMix rng{speed.seed};  // the project's generator: the same motion everywhere
  std::array<double, 4> f{}, ph{}, a{};
  double total = 0;
  for (std::size_t i = 0; i < 4; ++i) {
    f[i] = rng.uniform(0.02, 0.25);
    ph[i] = rng.uniform(0.0, 2 * M_PI);
    a[i] = rng.uniform(0.5, 1.0);
    total += a[i];
  }
  const double mid = (speed.min_speed + speed.max_speed) / 2, half = (speed.max_speed - speed.min_speed) / 2;
  double v = speed.kind == SpeedKind::kStopAndGo ? 0.0 : speed.min_speed;
  double s = 0;
  for (std::size_t k = 0; k <= steps; ++k) {
    const double t = static_cast<double>(k) * 1e-3;
    switch (speed.kind) {
      case SpeedKind::kConstant: v = speed.min_speed; break;
      case SpeedKind::kFluctuating: {
        double w = 0;
        for (std::size_t i = 0; i < 4; ++i) w += a[i] * std::sin(2 * M_PI * f[i] * t + ph[i]);
        v = mid + half * w / total;
        break;
      }
      case SpeedKind::kStopAndGo: {
        const double cycle = speed.stop_and_go_run_s + speed.stop_and_go_stop_s;
        const bool running = std::fmod(t, cycle) < speed.stop_and_go_run_s;
        const double target = running ? speed.max_speed : 0.0;
        const double dv = speed.accel * 1e-3;
        v = v < target ? std::min(target, v + dv) : std::max(target, v - dv);
        break;
      }
    }
    speed_[k] = v;
    distance_[k] = s;
    s += v * 1e-3;
  }
}

double LineMotion::distance(Nanos t) const {
  const double ms = std::clamp(static_cast<double>(t) / kNanosPerMilli, 0.0, static_cast<double>(distance_.size() - 2));
  const auto i = static_cast<std::size_t>(ms);
  const double frac = ms - static_cast<double>(i);
  return distance_[i] + frac * (distance_[i + 1] - distance_[i]);
}

double LineMotion::speed(Nanos t) const {
  const auto i = static_cast<std::size_t>(std::clamp<Nanos>(t / kNanosPerMilli, 0, static_cast<Nanos>(speed_.size() - 1)));
  return speed_[i];
}

double LineMotion::heading(Nanos t) const {
  const double s = distance(t);
  return s <= path_.curve_start_m ? 0.0 : path_.curvature * (s - path_.curve_start_m);
}

Eigen::Isometry3d LineMotion::X_Line_Panel(Nanos t) const {
  const double s = distance(t);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  if (s <= path_.curve_start_m || path_.curvature == 0.0) {
    X.translation() = Eigen::Vector3d(s, 0, 0);
    return X;
  }
  // An arc about the vertical axis: heading theta after the straight part.
  const double k = path_.curvature;
  const double theta = k * (s - path_.curve_start_m);
  X.translation() = Eigen::Vector3d(path_.curve_start_m + std::sin(theta) / k, 0, (1 - std::cos(theta)) / k);
  // Turning towards +z rotates the travel direction x towards z: about y by -theta.
  X.linear() = Eigen::AngleAxisd(-theta, Eigen::Vector3d::UnitY()).toRotationMatrix();
  return X;
}

}  // namespace markcell::rig
