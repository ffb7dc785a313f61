#pragma once
// A round or oval hole's centre in one view: a pressed panel's locating holes are among
// its most stable features, and their centre is not a corner (a corner detector moves
// it onto the rim). The hole's edge is found along kHoleRays fixed rays from a first
// guess (at the strongest step of the hole's polarity along each, the sub-pixel point
// where the grey crosses halfway between the two sides), an ellipse is fitted to the edge points
// (Fitzgibbon's direct least squares in Halir and Flusser's stable form, on fixed-size
// matrices), and the rays are cast again from its centre, where they meet the rim
// symmetrically. A circle seen at an angle is an ellipse; its projected centre differs
// from the ellipse's by far less than the fit's noise at the cell's geometry (a 30 mm
// hole at 3 m: under 0.001 px).
//
// Bounded time (kHoleRays x the ray's samples, two passes), no allocation: the tracker
// calls it on every frame for every hole MF.
#include <cstdint>
#include <string_view>

#include <Eigen/Core>

#include "markcell/vision/optical_flow.hpp"

namespace markcell::vision {

inline constexpr int kHoleRays = 32;
inline constexpr double kMaxHoleRadiusPx = 24;  // the rays' longest reach

enum class HoleFitStatus : std::uint8_t {
  kOk,
  kOutside,    // the rays would leave the image
  kFewEdges,   // fewer than half the rays met an edge of the hole's polarity
  kNoEllipse,  // the edge points are not on an ellipse (or a degenerate one)
  kRagged,     // they are, but scattered about it: not a clean hole edge
};
std::string_view to_string(HoleFitStatus s);

struct HoleFit {
  HoleFitStatus status = HoleFitStatus::kOutside;
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();  // level-0 pixels
  double semi_major = 0, semi_minor = 0;             // px
  double rms_px = 0;    // the edge points' distance from the ellipse (Sampson), rms
  int edges = 0;        // rays that met the edge (of kHoleRays)
  int polarity = 0;     // +1: the hole darker than the panel around it, -1: brighter
  bool ok() const { return status == HoleFitStatus::kOk; }
};

struct HoleFitParams {
  double min_radius = 1.0;   // the rays search from here ...
  double max_radius = 12.0;  // ... to here, px from the centre (at most kMaxHoleRadiusPx)
  double min_step = 4.0;     // an edge's grey step over one pixel, at least
  double max_rms_px = 0.35;  // the fit's rms beyond this: kRagged
  int polarity = 0;          // 0: found from the image; +1 / -1: that hole only
};

// The hole around `guess` on level 0 of `image`.
HoleFit fit_hole(const Pyramid& image, const Eigen::Vector2d& guess, const HoleFitParams& params);

}  // namespace markcell::vision
