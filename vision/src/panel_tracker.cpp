#include "markcell/vision/panel_tracker.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/core/persistence.hpp>

#include "markcell/common/check.hpp"
#include "markcell/common/geometry.hpp"
#include "markcell/vision/calibration_io.hpp"

namespace markcell::vision {

namespace {
int coarse_scale() { return 1 << kCoarseLevel; }

void snap_to_corner(const Pyramid& image, Eigen::Vector2d& p, int radius) {
  double best = -1;
  Eigen::Vector2d best_p = p;
  const int cx = static_cast<int>(std::lround(p.x())), cy = static_cast<int>(std::lround(p.y()));
  for (int y = cy - radius; y <= cy + radius; ++y)
    for (int x = cx - radius; x <= cx + radius; ++x) {
      if ((x - cx) * (x - cx) + (y - cy) * (y - cy) > radius * radius) continue;  // a disc, as --snap says
      const double s = shi_tomasi(image, x, y, 2);
      if (s > best) {
        best = s;
        best_p = {x, y};
      }
    }
  p = best_p;
}

// One row per MF: the patch `which` picks of it.
template <typename Which>
cv::Mat patches_to_mat(const PanelTypeModel& model, Which which) {
  const int r = which(model.mfs[0]).radius;
  const int n = (2 * r + 1) * (2 * r + 1);
  cv::Mat m(model.count(), n, CV_32F);
  for (int i = 0; i < model.count(); ++i)
    for (int k = 0; k < n; ++k) m.at<float>(i, k) = which(model.mfs[static_cast<std::size_t>(i)]).v[static_cast<std::size_t>(k)];
  return m;
}
}  // namespace

namespace {
std::string at(const Eigen::Vector2d& p) {
  char b[64];
  std::snprintf(b, sizeof b, "(%.2f, %.2f)", p.x(), p.y());
  return b;
}

// A hole's rays reach from 0.4 to 1.7 of its radius on the reference image: the panel's
// scale changes little along the line, and the rim stays well inside the range.
HoleFitParams hole_params(double radius_px) {
  HoleFitParams p;
  p.min_radius = std::max(0.4 * radius_px, 0.5);
  p.max_radius = std::min(1.7 * radius_px + 1.0, kMaxHoleRadiusPx);
  return p;
}

// The hole at the click: found from rays out to the snap radius (at least 14 px), then
// refined as the tracker refines it.
SnapResult snap_hole(const Pyramid& pyramid, const Eigen::Vector2d& clicked, int snap_radius) {
  SnapResult r;
  r.p = clicked;
  r.kind = MfKind::kHole;
  HoleFitParams wide;
  wide.max_radius = std::clamp<double>(snap_radius, 2.0 * kTemplateRadius, kMaxHoleRadiusPx);
  const HoleFit first = fit_hole(pyramid, clicked, wide);
  if (!first.ok()) {
    char b[200];
    std::snprintf(b, sizeof b, "no hole at %s: %s (%d of %d rays met an edge)", at(clicked).c_str(),
                  std::string(to_string(first.status)).c_str(), first.edges, kHoleRays);
    r.problem = b;
    return r;
  }
  const double radius = 0.5 * (first.semi_major + first.semi_minor);
  const HoleFit fit = fit_hole(pyramid, first.centre, hole_params(radius));
  if (!fit.ok()) {
    r.problem = "the hole at " + at(first.centre) + " does not refine: " + std::string(to_string(fit.status));
    return r;
  }
  r.p = fit.centre;
  r.hole_radius_px = 0.5 * (fit.semi_major + fit.semi_minor);
  r.moved_px = (r.p - clicked).norm();
  if (fit.semi_major > kMaxHoleMfRadiusPx) {
    char b[200];
    std::snprintf(b, sizeof b, "the hole at %s has a radius of %.1f px: at most %.0f px fits the %d-px template",
                  at(r.p).c_str(), fit.semi_major, kMaxHoleMfRadiusPx, 2 * kTemplateRadius + 1);
    r.problem = b;
  }
  return r;
}

// Is the click inside a clean hole? (For a click that asks for neither kind.)
bool looks_like_hole(const SnapResult& hole, const Eigen::Vector2d& clicked, const Pyramid& pyramid) {
  if (!hole.ok()) return false;
  const HoleFit again = fit_hole(pyramid, hole.p, hole_params(hole.hole_radius_px));
  return again.ok() && again.edges * 4 >= 3 * kHoleRays && again.rms_px <= 0.2 && again.semi_minor >= 1.5 &&
         (clicked - again.centre).norm() < again.semi_minor;
}

// Also cuts the MF's two templates (fine, coarse), which say whether it is usable there.
SnapResult snap(const Pyramid& pyramid, const Eigen::Vector2d& clicked, int snap_radius, MfKindRequest kind, Patch& fine,
                Patch& coarse) {
  SnapResult r;
  bool hole = kind == MfKindRequest::kHole;
  if (kind != MfKindRequest::kCorner) {
    r = snap_hole(pyramid, clicked, snap_radius);
    hole = hole || looks_like_hole(r, clicked, pyramid);
  }
  if (!hole) {
    r = SnapResult{};
    r.p = clicked;
    if (snap_radius > 0) snap_to_corner(pyramid, r.p, snap_radius);
    if (!refine_corner(pyramid, r.p, 5)) {
      r.problem = "no corner near " + at(clicked) + " (or too close to the border)";
      return r;
    }
    // Plain panel refines too (onto its texture and noise): a corner is an edge turning,
    // far stronger than both.
    const double strength = shi_tomasi(pyramid, static_cast<int>(std::lround(r.p.x())), static_cast<int>(std::lround(r.p.y())), 2);
    if (strength < kMinCornerStrength) {
      char b[200];
      std::snprintf(b, sizeof b, "no corner near %s: the strongest there scores %.1f, a corner needs %.0f (Shi-Tomasi, grey^2 per pixel)",
                    at(clicked).c_str(), strength, kMinCornerStrength);
      r.problem = b;
      return r;
    }
  } else if (!r.ok()) {
    return r;
  }
  const char* what = hole ? "hole centre" : "corner";
  r.moved_px = (r.p - clicked).norm();
  if (r.moved_px > snap_limit_px(snap_radius)) {
    char b[200];
    std::snprintf(b, sizeof b, "the %s found is %.2f px from the click at %s, at %s: beyond the snap radius of %d px", what,
                  r.moved_px, at(clicked).c_str(), at(r.p).c_str(), snap_radius);
    r.problem = b;
    return r;
  }
  // Usable only where both of its templates can be cut.
  if (!extract_patch(pyramid, 0, r.p, kTemplateRadius, fine) ||
      !extract_patch(pyramid, kCoarseLevel, r.p / coarse_scale(), kTemplateRadius / 2 + 1, coarse))
    r.problem = std::string("the ") + what + " at " + at(r.p) + " is too close to the image border for its template";
  return r;
}
}  // namespace

std::string_view to_string(MfKind k) {
  switch (k) {
    case MfKind::kCorner: return "corner";
    case MfKind::kHole: return "hole";
    case MfKind::kUnseen: return "unseen";
  }
  return "?";
}

double snap_limit_px(int snap_radius) { return std::max(snap_radius, 1); }

SnapResult snap_macro_feature(const cv::Mat& reference_left, const Eigen::Vector2d& clicked, int snap_radius,
                              MfKindRequest kind) {
  Pyramid pyramid(reference_left.cols, reference_left.rows, kCoarseLevel + 1);
  pyramid.build(reference_left);
  Patch fine, coarse;
  return snap(pyramid, clicked, snap_radius, kind, fine, coarse);
}

PanelTypeModel make_panel_type(const std::string& name, const cv::Mat& reference_left, const std::vector<MfPick>& picks,
                               int snap_radius, int search_x, int search_y) {
  MARKCELL_THROW_UNLESS(picks.size() >= 3 && picks.size() <= static_cast<std::size_t>(kMaxMacroFeatures),
                        "panel type '" << name << "' has " << picks.size() << " macro-features, 3.."
                                       << kMaxMacroFeatures << " are needed");
  Pyramid pyramid(reference_left.cols, reference_left.rows, kCoarseLevel + 1);
  pyramid.build(reference_left);
  PanelTypeModel m;
  m.name = name;
  m.image_width = reference_left.cols;
  m.image_height = reference_left.rows;
  m.search_x = search_x;
  m.search_y = search_y;
  for (int i = 0; i < static_cast<int>(picks.size()); ++i) {
    const auto k = static_cast<std::size_t>(i);
    PanelTypeModel::Mf& mf = *m.mfs.emplace_back();  // (at most kMaxMacroFeatures: checked above)
    if (picks[k].kind == MfKindRequest::kUnseen) {  // kept in the order, with empty templates
      mf.reference_px = picks[k].px;
      mf.kind = MfKind::kUnseen;
      mf.template_patch.radius = kTemplateRadius;
      mf.coarse_template.radius = kTemplateRadius / 2 + 1;
      continue;
    }
    const SnapResult r = snap(pyramid, picks[k].px, snap_radius, picks[k].kind, mf.template_patch, mf.coarse_template);
    if (!r.ok()) throw std::invalid_argument("panel type '" + name + "': macro-feature " + std::to_string(i + 1) + ": " + r.problem);
    mf.reference_px = r.p;
    mf.kind = r.kind;
    mf.hole_radius_px = r.hole_radius_px;
  }
  return m;
}

void save_panel_type(const std::string& path, const PanelTypeModel& m) {
  cv::FileStorage fs(path, cv::FileStorage::WRITE);
  if (!fs.isOpened()) throw std::runtime_error(path + ": cannot write");
  fs << "panel_type" << m.name << "image_width" << m.image_width << "image_height" << m.image_height;
  fs << "search_x_px" << m.search_x << "search_y_px" << m.search_y;
  cv::Mat px(m.count(), 2, CV_64F);
  for (int i = 0; i < m.count(); ++i) {
    px.at<double>(i, 0) = m.mfs[static_cast<std::size_t>(i)].reference_px.x();
    px.at<double>(i, 1) = m.mfs[static_cast<std::size_t>(i)].reference_px.y();
  }
  fs << "macro_features" << px;
  fs << "kinds" << "[";
  for (const auto& mf : m.mfs) fs << std::string(to_string(mf.kind));
  fs << "]";
  fs << "hole_radius_px" << "[";
  for (const auto& mf : m.mfs) fs << mf.hole_radius_px;
  fs << "]";
  fs << "templates" << patches_to_mat(m, [](const PanelTypeModel::Mf& mf) -> const Patch& { return mf.template_patch; });
  fs << "coarse_templates" << patches_to_mat(m, [](const PanelTypeModel::Mf& mf) -> const Patch& { return mf.coarse_template; });
}

PanelTypeModel load_panel_type(const std::string& path) {
  // Templates of up to 16 MFs at two scales: 4 MiB is far more than any needs.
  cv::FileStorage fs = open_yaml_storage(path, 4 << 20, "a panel-type file");
  auto need = [&](const char* key) {
    const cv::FileNode n = fs[key];
    if (n.empty()) throw std::runtime_error(path + ": missing key '" + key + "'");
    return n;
  };
  PanelTypeModel m;
  m.name = static_cast<std::string>(need("panel_type"));
  m.image_width = static_cast<int>(need("image_width"));
  m.image_height = static_cast<int>(need("image_height"));
  m.search_x = static_cast<int>(need("search_x_px"));
  m.search_y = static_cast<int>(need("search_y_px"));
  cv::Mat px, t, ct;
  need("macro_features") >> px;
  need("templates") >> t;
  need("coarse_templates") >> ct;
  if (px.cols != 2 || px.rows < 3 || px.rows > kMaxMacroFeatures || px.type() != CV_64F)
    throw std::runtime_error(path + ": 'macro_features' must be an Nx2 double matrix, 3 <= N <= " +
                             std::to_string(kMaxMacroFeatures));
  for (int i = 0; i < px.rows; ++i) m.mfs.emplace_back()->reference_px = {px.at<double>(i, 0), px.at<double>(i, 1)};
  // Kinds and hole radii: a file from before holes has neither, and its MFs are corners.
  const cv::FileNode kinds = fs["kinds"], radii = fs["hole_radius_px"];
  if (!kinds.empty() || !radii.empty()) {
    if (!kinds.isSeq() || static_cast<int>(kinds.size()) != m.count() || !radii.isSeq() || static_cast<int>(radii.size()) != m.count())
      throw std::runtime_error(path + ": 'kinds' and 'hole_radius_px' must list one entry per macro-feature (" +
                               std::to_string(m.count()) + ")");
    for (int i = 0; i < m.count(); ++i) {
      PanelTypeModel::Mf& mf = m.mfs[static_cast<std::size_t>(i)];
      const cv::FileNode k = kinds[i], r = radii[i];
      const std::string kind = k.isString() ? static_cast<std::string>(k) : std::string();
      if (kind != "corner" && kind != "hole" && kind != "unseen")
        throw std::runtime_error(path + ": 'kinds' entry " + std::to_string(i + 1) + " must be corner, hole or unseen");
      mf.kind = kind == "hole" ? MfKind::kHole : kind == "unseen" ? MfKind::kUnseen : MfKind::kCorner;
      mf.hole_radius_px = r.isReal() || r.isInt() ? static_cast<double>(r) : -1.0;
      const bool fits = mf.kind == MfKind::kHole ? mf.hole_radius_px >= 1.0 && mf.hole_radius_px <= kMaxHoleMfRadiusPx
                                                 : mf.hole_radius_px == 0.0;
      if (!fits)
        throw std::runtime_error(path + ": 'hole_radius_px' entry " + std::to_string(i + 1) + " must be " +
                                 (mf.kind == MfKind::kHole ? "1.." + std::to_string(static_cast<int>(kMaxHoleMfRadiusPx)) +
                                                                 " px for a hole"
                                                           : std::string("0 for a corner or an unseen MF")));
    }
  }
  auto read_patches = [&](const cv::Mat& mat, const char* key, int radius, Patch PanelTypeModel::Mf::*out) {
    const int n = (2 * radius + 1) * (2 * radius + 1);
    if (mat.rows != m.count() || mat.cols != n || mat.type() != CV_32F)
      throw std::runtime_error(path + ": '" + key + "' must be " + std::to_string(m.count()) + "x" + std::to_string(n) +
                               " float, is " + std::to_string(mat.rows) + "x" + std::to_string(mat.cols));
    for (int i = 0; i < m.count(); ++i) {
      Patch& patch = m.mfs[static_cast<std::size_t>(i)].*out;
      patch.radius = radius;
      for (int k = 0; k < n; ++k) patch.v[static_cast<std::size_t>(k)] = mat.at<float>(i, k);
    }
  };
  read_patches(t, "templates", kTemplateRadius, &PanelTypeModel::Mf::template_patch);
  read_patches(ct, "coarse_templates", kTemplateRadius / 2 + 1, &PanelTypeModel::Mf::coarse_template);
  if (m.search_x < 0 || m.search_y < 0) throw std::runtime_error(path + ": search_x_px and search_y_px must be >= 0");
  return m;
}

PanelTracker::PanelTracker(const StereoRig& rig, const PanelTypeModel& model, const TrackerParams& params)
    : rig_(rig),
      model_(model),
      params_(params),
      level0_lk_([&] {
        LkParams p = params.lk;
        p.max_levels = 1;
        return p;
      }()),
      left_{Pyramid(rig.width(), rig.height(), std::max(params.pyramid_levels, kCoarseLevel + 1)),
            Pyramid(rig.width(), rig.height(), std::max(params.pyramid_levels, kCoarseLevel + 1))},
      right_(rig.width(), rig.height(), std::max(params.pyramid_levels, kCoarseLevel + 1)) {
  MARKCELL_THROW_UNLESS(model.image_width == rig.width() && model.image_height == rig.height(),
                        "panel type '" << model.name << "' was picked on " << model.image_width << "x"
                                       << model.image_height << " images, the cameras give " << rig.width() << "x"
                                       << rig.height());
  MARKCELL_THROW_UNLESS(params.min_macro_features >= 3 && params.min_macro_features <= model.count(),
                        "min_macro_features=" << params.min_macro_features << " with " << model.count() << " MFs");
  for (int i = 0; i < model.count(); ++i)
    hole_params_[static_cast<std::size_t>(i)] = hole_params(model.mfs[static_cast<std::size_t>(i)].hole_radius_px);
}

void PanelTracker::reset() {
  searching_ = true;
  have_previous_ = false;
  lost_frames_ = 0;
  known_.fill(false);
  tracked_.fill(false);
}

const StereoMeasurement& PanelTracker::measure(const cv::Mat& left, const cv::Mat& right) {
  reset();
  const PoseEstimate& e = process(0, 0, left, right);
  reset();  // the next pair is another panel's
  StereoMeasurement& m = measurement_;
  m.mfs.clear();
  m.found = 0;
  m.reason = e.status == TrackStatus::kReinitialised ? std::string_view() : e.reason;
  const Pyramid& L = left_[cur_];
  const Eigen::Isometry3d X_CamL_CamR = rig_.calibration().X_CamR_CamL.inverse();
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    MfMeasurement& out = *m.mfs.emplace_back();  // bounded: kMaxMacroFeatures MFs a model
    const MacroFeatureObservation& o = e.mfs[k];
    if (!o.valid) continue;
    out.found = true;
    ++m.found;
    out.left = o.left;
    out.right = o.right;
    out.p_CamL = X_CamL_CamR * o.p_CamR;
    out.epipolar_px = rig_.epipolar_distance(rig_.undistort(Camera::kLeft, o.left), rig_.undistort(Camera::kRight, o.right));
    if (model_.mfs[k].kind == MfKind::kCorner) {
      out.corner_response =
          shi_tomasi(L, static_cast<int>(std::lround(o.left.x())), static_cast<int>(std::lround(o.left.y())), 2);
    } else {
      const HoleFit fit = fit_hole(L, o.left, hole_params_[k]);
      out.hole_rms_px = fit.ok() ? fit.rms_px : 0.0;
    }
  }
  return m;
}

void PanelTracker::set_reference(int mf, const Eigen::Vector3d& p_P) {
  if (mf < 0 || mf >= model_.count()) return;
  const auto k = static_cast<std::size_t>(mf);
  reference_P_[k] = first_P_[k] = sum_P_[k] = p_P;
  samples_[k] = 1;
  observed_[k] = 0;
  known_[k] = true;
}

const PoseEstimate& PanelTracker::process(std::uint64_t seq, Nanos time, const cv::Mat& left, const cv::Mat& right) {
  cur_ ^= 1;
  left_[cur_].build(left);
  right_.build(right);
  estimate_.seq = seq;
  estimate_.time = time;
  estimate_.reason = {};
  estimate_.mfs.clear();
  for (int i = 0; i < model_.count(); ++i) estimate_.mfs.emplace_back();
  if (searching_ || !have_previous_) reinitialise();
  else track();
  have_previous_ = true;
  for (std::size_t k = 0; k < estimate_.mfs.size(); ++k) {
    estimate_.mfs[k].reference_P = reference_P_[k];
    estimate_.mfs[k].reference_known = known_[k];
    estimate_.mfs[k].reference_observed = observed_[k];
  }
  return estimate_;
}

double PanelTracker::epipolar_row(const Eigen::Vector2d& left, const Eigen::Vector2d& right) const {
  return rig_.rectify(Camera::kRight, right).y() - rig_.rectify(Camera::kLeft, left).y();
}

bool PanelTracker::refine(int mf, const Pyramid& image, Eigen::Vector2d& p) const {
  const PanelTypeModel::Mf& m = model_.mfs[static_cast<std::size_t>(mf)];
  if (m.kind == MfKind::kCorner) return refine_corner(image, p, params_.corner_radius);
  const HoleFit fit = fit_hole(image, p, hole_params_[static_cast<std::size_t>(mf)]);
  if (!fit.ok() || (fit.centre - p).norm() > m.hole_radius_px) return false;
  p = fit.centre;
  return true;
}

bool PanelTracker::verify_pair(int mf, const Eigen::Vector2d& left, const Eigen::Vector2d& right) const {
  // The right view must show the corner (or the hole) there too, but the pair's disparity
  // is LK's: a photometric alignment of the left window onto the right view, whose error
  // does not depend on where the corner falls between pixels. Two corner refinements, one
  // per view, each carry their own sub-pixel bias (about 0.1 px) into the disparity: 2 mm
  // of depth.
  Eigen::Vector2d corner = right;
  if (!refine(mf, right_, corner) || (corner - right).norm() > params_.corner_agree_px) return false;
  const double d = rig_.epipolar_distance(rig_.undistort(Camera::kLeft, left), rig_.undistort(Camera::kRight, right));
  if (!(d <= params_.epipolar_px)) return false;
  const Eigen::Vector3d p = rig_.triangulate_observed(left, right);
  return p.z() >= params_.depth_min && p.z() <= params_.depth_max;
}

bool PanelTracker::find_right(int mf, const Eigen::Vector2d& left, Eigen::Vector2d& right) const {
  // Walk the left pixel's epipolar segment between the nearest and farthest panel depth
  // in the right view, at one-pixel steps, for the best template match; then LK from the
  // left view refines it and the corner refinement and epipolar check confirm it.
  const Pyramid& L = left_[cur_];
  const Eigen::Vector2d u = rig_.undistort(Camera::kLeft, left);
  const Eigen::Matrix3d& K = rig_.calibration().left.K;
  const Eigen::Vector3d ray_L((u.x() - K(0, 2)) / K(0, 0), (u.y() - K(1, 2)) / K(1, 1), 1.0);
  const Eigen::Isometry3d& X_R_L = rig_.calibration().X_CamR_CamL;
  const Eigen::Vector2d a = rig_.project(Camera::kRight, X_R_L * (ray_L * params_.depth_max));
  const Eigen::Vector2d b = rig_.project(Camera::kRight, X_R_L * (ray_L * params_.depth_min));
  const int steps = std::min(static_cast<int>(std::ceil((b - a).norm())), 2 * (rig_.width() + rig_.height()));
  Patch patch;
  if (!extract_patch(L, 0, left, kTemplateRadius, patch)) return false;
  double best = -1;
  Eigen::Vector2d best_p = a;
  for (int s = 0; s <= steps; ++s) {
    const Eigen::Vector2d q = steps > 0 ? Eigen::Vector2d(a + (b - a) * (static_cast<double>(s) / steps)) : a;
    for (int dy = -1; dy <= 1; ++dy) {  // the segment is straight only without distortion
      const double score = ncc(patch, right_, 0, static_cast<int>(std::lround(q.x())), static_cast<int>(std::lround(q.y())) + dy);
      if (score > best) {
        best = score;
        best_p = {std::round(q.x()), std::round(q.y()) + dy};
      }
    }
  }
  if (best < params_.min_ncc) return false;
  const LkResult lk = track_point(L, right_, left, best_p, params_.lk);
  if (lk.status != LkStatus::kOk) return false;
  right = lk.point;
  return verify_pair(mf, left, right);
}

void PanelTracker::reinitialise() {
  const Pyramid& L = left_[cur_];
  const int s = coarse_scale();
  // 1. The panel's shift from the reference image: every MF moves (nearly) alike, so the
  //    shift that matches the most templates best wins, searched on the coarse level.
  double best_score = 0;
  int best_dx = 0, best_dy = 0;
  const int rx = model_.search_x / s, ry = model_.search_y / s;
  for (int dy = -ry; dy <= ry; ++dy)
    for (int dx = -rx; dx <= rx; ++dx) {
      double score = 0;
      int seen = 0;
      for (int i = 0; i < model_.count(); ++i) {
        if (model_.mfs[static_cast<std::size_t>(i)].kind == MfKind::kUnseen) continue;
        const Eigen::Vector2d& r = model_.mfs[static_cast<std::size_t>(i)].reference_px;
        const double c = ncc(model_.mfs[static_cast<std::size_t>(i)].coarse_template, L, kCoarseLevel,
                             static_cast<int>(std::lround(r.x() / s)) + dx, static_cast<int>(std::lround(r.y() / s)) + dy);
        if (c > 0) score += c, ++seen;
      }
      if (seen >= params_.min_macro_features && score > best_score) {
        best_score = score;
        best_dx = dx;
        best_dy = dy;
      }
    }
  // 2. Each MF at full resolution around its shifted reference, then its corner; 3. its
  //    partner in the right view along the epipolar line; 4. triangulated.
  int found = 0;
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    known_[k] = false;
    tracked_[k] = false;
    observed_[k] = 0;
    set_up_[k] = false;
    if (best_score <= 0 || model_.mfs[k].kind == MfKind::kUnseen) continue;
    Eigen::Vector2d guess = model_.mfs[k].reference_px + Eigen::Vector2d(best_dx * s, best_dy * s);
    // Each MF's own offset from the common shift (a panel turned, or nearer than the
    // reference, moves its MFs unequally), on the coarse level, within reinit_local_px.
    if (const int local = params_.reinit_local_px / s; local > 0) {
      const int cx = static_cast<int>(std::lround(guess.x() / s)), cy = static_cast<int>(std::lround(guess.y() / s));
      double best_local = -2;
      Eigen::Vector2d moved = guess;
      for (int dy = -local; dy <= local; ++dy)
        for (int dx = -local; dx <= local; ++dx) {
          const double c = ncc(model_.mfs[k].coarse_template, L, kCoarseLevel, cx + dx, cy + dy);
          if (c > best_local) best_local = c, moved = Eigen::Vector2d((cx + dx) * s, (cy + dy) * s);
        }
      guess = moved;
    }
    double best = -1;
    Eigen::Vector2d p = guess;
    const int gx = static_cast<int>(std::lround(guess.x())), gy = static_cast<int>(std::lround(guess.y()));
    for (int y = gy - s - 2; y <= gy + s + 2; ++y)
      for (int x = gx - s - 2; x <= gx + s + 2; ++x) {
        const double c = ncc(model_.mfs[k].template_patch, L, 0, x, y);
        if (c > best) best = c, p = {x, y};
      }
    if (best < params_.min_ncc || !refine(i, L, p)) continue;
    Eigen::Vector2d r;
    if (!find_right(i, p, r)) continue;
    auto& o = estimate_.mfs[k];
    o.valid = o.inlier = true;
    o.left = p;
    o.right = r;
    o.p_CamR = rig_.triangulate_observed(p, r);
    reference_P_[k] = first_P_[k] = sum_P_[k] = o.p_CamR;
    samples_[k] = observed_[k] = 1;
    set_up_[k] = true;
    known_[k] = tracked_[k] = true;
    prev_left_[k] = p;
    prev_right_[k] = r;
    row_[k] = epipolar_row(p, r);
    velocity_[k].setZero();
    patch_[k] = model_.mfs[k].template_patch;
    extract_patch(L, 0, p, kTemplateRadius, patch_[k]);
    ++found;
  }
  estimate_.tracked = estimate_.inliers = found;
  estimate_.rms = 0;
  if (found < params_.min_macro_features) {
    known_.fill(false);
    tracked_.fill(false);
    estimate_.status = TrackStatus::kSearching;
    estimate_.reason = best_score <= 0 ? "no position of the panel type's template set matches"
                                       : "too few macro-features found in both views";
    searching_ = true;
    return;
  }
  for (int i = 0; i < model_.count(); ++i)
    if (!known_[static_cast<std::size_t>(i)]) patch_[static_cast<std::size_t>(i)] = model_.mfs[static_cast<std::size_t>(i)].template_patch;
  estimate_.status = TrackStatus::kReinitialised;
  estimate_.X_CamR_P = Eigen::Isometry3d::Identity();
  ++estimate_.reference_serial;
  estimate_.reference_time = estimate_.time;
  searching_ = false;
  lost_frames_ = 0;
}

void PanelTracker::track() {
  const Pyramid& prev = left_[cur_ ^ 1];
  const Pyramid& L = left_[cur_];
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (!tracked_[k]) continue;
    tracked_[k] = false;
    // Frame to frame in the left view, seeded by the MF's last motion, checked backwards.
    const LkResult fwd = track_point(prev, L, prev_left_[k], prev_left_[k] + velocity_[k], params_.lk);
    if (fwd.status != LkStatus::kOk) continue;
    // Backwards the answer is known to within the check's tolerance: level 0 suffices.
    const LkResult back = track_point(L, prev, fwd.point, prev_left_[k], level0_lk_);
    if (back.status != LkStatus::kOk || (back.point - prev_left_[k]).norm() > params_.forward_backward_px) continue;
    Eigen::Vector2d left = fwd.point;
    if (!refine(i, L, left)) continue;
    // Left to right, seeded by the last disparity.
    // The disparity changes little between frames: level 0 first, the pyramid if that fails.
    LkResult lr = track_point(L, right_, left, left + (prev_right_[k] - prev_left_[k]), level0_lk_);
    if (lr.status != LkStatus::kOk) lr = track_point(L, right_, left, left + (prev_right_[k] - prev_left_[k]), params_.lk);
    if (lr.status != LkStatus::kOk) continue;
    Eigen::Vector2d right = lr.point;
    if (!verify_pair(i, left, right)) continue;
    // The pair's rectified row difference is the calibration's residual at that point of
    // the panel and changes little from frame to frame; a jump is a match pulled off by
    // something crossing one view's window (the arm's edge): a fraction of a pixel of
    // disparity, millimetres of depth that a pose on four or five MFs levers out to the
    // dings. Such an MF is left out and picked up again by reacquire.
    const double row = epipolar_row(left, right);
    if (std::abs(row - row_[k]) > params_.epipolar_jump_px) continue;
    row_[k] = row;
    auto& o = estimate_.mfs[k];
    o.valid = true;
    o.left = left;
    o.right = right;
    o.p_CamR = rig_.triangulate_observed(left, right);
    velocity_[k] = left - prev_left_[k];
    prev_left_[k] = left;
    prev_right_[k] = right;
    tracked_[k] = true;
  }
  fit_pose();
  if (estimate_.has_pose()) reacquire();
}

void PanelTracker::fit_pose() {
  std::array<Eigen::Vector3d, kMaxMacroFeatures> a{}, b{};
  std::array<int, kMaxMacroFeatures> which{};
  std::array<bool, kMaxMacroFeatures> inlier{};
  std::size_t n = 0;
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (!estimate_.mfs[k].valid || !known_[k]) continue;
    a[n] = reference_P_[k];
    b[n] = estimate_.mfs[k].p_CamR;
    which[n++] = i;
  }
  estimate_.tracked = static_cast<int>(n);
  geometry::RigidFit fit;
  if (static_cast<int>(n) >= params_.min_macro_features) {
    geometry::RobustFitOptions options;
    options.inlier_threshold = params_.inlier_m;
    options.max_iterations = params_.ransac_iterations;
    options.seed = estimate_.seq + 1;
    fit = geometry::fit_rigid_robust(std::span(a.data(), n), std::span(b.data(), n), options, std::span(inlier.data(), n));
  }
  if (!fit.valid || fit.used < params_.min_macro_features) {
    estimate_.status = TrackStatus::kLost;
    estimate_.reason = "too few macro-features consistent with a rigid motion";
    estimate_.inliers = fit.valid ? fit.used : 0;
    if (++lost_frames_ >= params_.lost_frames_to_reinit) {
      searching_ = true;  // the next frame searches for the MFs anew
      tracked_.fill(false);
    }
    return;
  }
  lost_frames_ = 0;
  for (std::size_t j = 0; j < n; ++j) {
    const auto k = static_cast<std::size_t>(which[j]);
    estimate_.mfs[k].inlier = inlier[j];
    if (!inlier[j]) tracked_[k] = false;  // broke the rigid motion: picked up again by reacquire
  }
  estimate_.status = TrackStatus::kTracking;
  estimate_.X_CamR_P = fit.X_B_A;
  estimate_.inliers = fit.used;
  estimate_.rms = fit.rms;
  refine_reference(fit.X_B_A);
}

void PanelTracker::refine_reference(const Eigen::Isometry3d& X_CamR_P) {
  // One frame's triangulation fixes each MF's position in P to the stereo pair's depth
  // noise; when the arm hides part of the set, the pose rests on a few MFs and their
  // errors, levered out to a defect far from them, move it by several times as much. So
  // every inlier's observation, taken back into P by the pose, is averaged into its
  // position (Procrustes over frames). The averaged set is then laid by a rigid fit onto
  // the MFs found when P was set up, so that P stays where it was: the tool poses live in
  // it. (MFs placed through the record are left out of that fit: they carry the first
  // inter-calibration's errors, levered out from the few MFs in view then.)
  const Eigen::Isometry3d X_P_CamR = X_CamR_P.inverse();
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (!estimate_.mfs[k].inlier || !known_[k]) continue;
    observed_[k] = std::min(observed_[k] + 1, 1 << 30);
    if (samples_[k] >= params_.reference_samples) continue;
    sum_P_[k] += X_P_CamR * estimate_.mfs[k].p_CamR;
    ++samples_[k];
  }
  std::array<Eigen::Vector3d, kMaxMacroFeatures> mean{}, first{};
  std::size_t n = 0;
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (!known_[k] || !set_up_[k]) continue;  // P is where the MFs found at set-up put it
    mean[n] = sum_P_[k] / samples_[k];
    first[n++] = first_P_[k];
  }
  const geometry::RigidFit pin = geometry::fit_rigid(std::span(mean.data(), n), std::span(first.data(), n));
  if (!pin.valid) return;
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (known_[k]) reference_P_[k] = pin.X_B_A * (sum_P_[k] / samples_[k]);
  }
}

void PanelTracker::reacquire() {
  // MFs not tracked (occluded, out of view, rejected) whose position on the panel is
  // known: look where the pose puts them; accept a corner that matches its template,
  // pairs on the epipolar line and lands where the pose says.
  const Pyramid& L = left_[cur_];
  for (int i = 0; i < model_.count(); ++i) {
    const auto k = static_cast<std::size_t>(i);
    if (tracked_[k] || !known_[k] || model_.mfs[k].kind == MfKind::kUnseen) continue;
    const Eigen::Vector3d p = estimate_.X_CamR_P * reference_P_[k];
    Eigen::Vector2d left = rig_.project(Camera::kLeft, p), right = rig_.project(Camera::kRight, p);
    if (!L.inside(0, left.x(), left.y(), params_.lk.radius + 2) || !right_.inside(0, right.x(), right.y(), params_.lk.radius + 2))
      continue;
    if (ncc(patch_[k], L, 0, static_cast<int>(std::lround(left.x())), static_cast<int>(std::lround(left.y()))) < params_.min_ncc)
      continue;
    if (!refine(i, L, left)) continue;
    // The pose's projection is within a pixel or two: level 0 suffices.
    const LkResult lr = track_point(L, right_, left, right + (left - rig_.project(Camera::kLeft, p)), level0_lk_);
    if (lr.status != LkStatus::kOk) continue;
    right = lr.point;
    if (!verify_pair(i, left, right)) continue;
    if ((rig_.triangulate_observed(left, right) - p).norm() > params_.inlier_m) continue;
    prev_left_[k] = left;
    prev_right_[k] = right;
    row_[k] = epipolar_row(left, right);
    velocity_[k].setZero();
    tracked_[k] = true;  // used from the next frame on
  }
}

}  // namespace markcell::vision
