#pragma once
// Inspection station to marking station, once per panel (paper III.A, Table I): the
// macro-features as the inspection station measured them (CamL_SL, "SL") and as the
// marking station just found them (P, the panel frame the tracker set up) give X_P_SL by
// a robust Arun fit; its error report is the max |error| and the RMS per axis, in P.
//
// The error at the MFs says nothing about a defect far from them: a few MFs close
// together (a panel entering the view, a re-search after an occlusion) pin the fit's
// rotation down poorly, and a defect half a metre away is placed centimetres off while
// the MFs agree to a millimetre. The fit's covariance (Gauss-Markov, from the inliers'
// layout and their residuals) gives each defect its own placement uncertainty.
#include <array>
#include <cstdint>
#include <span>
#include <string_view>

#include <Eigen/Geometry>

namespace markcell::control {

inline constexpr int kMaxIntercalibrationPoints = 16;

struct IntercalibrationLimits {
  double max_abs_error = 0.02;   // m, per axis: above it the panel is not marked
  double inlier_threshold = 0.02;  // m, RANSAC consensus
  int min_points = 4;
  int max_outliers = 2;  // more MFs than this disagreeing with the fit: the record is not this panel's
  double point_sigma = 0.0005;   // m: one MF's noise at least (both stations'), whatever the residuals say
  double max_placement_sigma = 0.001;  // m: a defect placed less surely than this is not sprayed
};

enum class IntercalibrationStatus : std::uint8_t { kOk, kTooFewPoints, kDegenerate, kAboveLimit, kOutliers };
std::string_view to_string(IntercalibrationStatus s);

struct Intercalibration {
  IntercalibrationStatus status = IntercalibrationStatus::kTooFewPoints;
  Eigen::Isometry3d X_P_SL = Eigen::Isometry3d::Identity();
  Eigen::Vector3d max_abs = Eigen::Vector3d::Zero();  // per axis of P, over the inliers, m
  Eigen::Vector3d rms = Eigen::Vector3d::Zero();
  int paired = 0;    // MFs known on both sides
  int inliers = 0;   // used in the fit
  // The fit's covariance: translation at the inliers' centroid (in P) and rotation, m and rad.
  Eigen::Vector3d centroid_P = Eigen::Vector3d::Zero();
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  bool ok() const { return status == IntercalibrationStatus::kOk; }
  // The standard deviation, along its worst direction, of a point the fit places at p_P, m.
  double placement_sigma(const Eigen::Vector3d& p_P) const;
};

// mfs_SL[i] and mfs_P[i] are the same MF (the panel type's order); known_P[i] says
// whether the marking station found it. Bounded, no allocation.
Intercalibration intercalibrate(std::span<const Eigen::Vector3d> mfs_SL, std::span<const Eigen::Vector3d> mfs_P,
                                std::span<const bool> known_P, const IntercalibrationLimits& limits);

}  // namespace markcell::control
