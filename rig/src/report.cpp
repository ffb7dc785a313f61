// The rig's report: report.json (fields in docs/rig.md), the plots
// (paper Figs. 5, 6 and 8, and the spray points on a frame) and the printed tables.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "markcell/common/bounded_file.hpp"
#include "markcell/common/log_escape.hpp"
#include "markcell/host/inspection_record.hpp"
#include "markcell/host/json.hpp"
#include "markcell/rig/replay.hpp"
#include "markcell/vision/frame_source.hpp"
#include "markcell/vision/panel_tracker.hpp"
#include "markcell/vision/recording.hpp"
#include "markcell/vision/stereo_rig.hpp"

namespace markcell::rig {

std::optional<InspectionFigures> inspection_figures(const std::string& recording) {
  const std::filesystem::path path = std::filesystem::path(recording) / "inspection" / "mfs.csv";
  std::string text;
  try {
    text = read_bounded_file(path.string(), 1 << 20, "the inspection station's MF table");
  } catch (const std::exception&) {
    return std::nullopt;
  }
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line) || line.rfind("mf,found,", 0) != 0) return std::nullopt;
  InspectionFigures f;
  std::vector<double> epipolar, error;
  while (std::getline(in, line) && f.mfs < 64) {
    std::vector<std::string> cells(1);  // every field, the empty last one of an MF not found too
    for (const char c : line)
      if (c == ',') cells.emplace_back();
      else cells.back() += c;
    if (cells.size() < 14) return std::nullopt;
    ++f.mfs;
    if (cells[1] != "1") continue;
    ++f.measured;
    try {
      epipolar.push_back(std::stod(cells[6]));
      error.push_back(std::stod(cells[13]));
    } catch (const std::exception&) {
      return std::nullopt;
    }
  }
  const auto median = [](std::vector<double> v) {
    if (v.empty()) return 0.0;
    std::sort(v.begin(), v.end());
    return v.size() % 2 == 1 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  };
  f.epipolar_median = median(epipolar);
  f.error_median_mm = median(error);
  f.epipolar_max = epipolar.empty() ? 0.0 : *std::max_element(epipolar.begin(), epipolar.end());
  f.error_max_mm = error.empty() ? 0.0 : *std::max_element(error.begin(), error.end());
  f.errors_mm = error;
  return f;
}


// The rig runs the service's cell: its configuration, its cell and their helpers.
using namespace markcell::host;

namespace {

using Json = nlohmann::ordered_json;  // members in the order written: the report reads as docs/rig.md lists it

// A figure rounded to `digits` decimals before it goes in, so that the same run always
// prints the same bytes; not finite: null.
Json num(double v, int digits = 3) {
  if (!std::isfinite(v)) return nullptr;
  const double scale = std::pow(10.0, digits);
  return std::round(v * scale) / scale;
}
Json vec(const Eigen::Vector3d& v, double scale, int digits = 3) {
  return Json::array({num(v.x() * scale, digits), num(v.y() * scale, digits), num(v.z() * scale, digits)});
}
// A figure as text with fixed decimals (the plots' labels, the printed tables).
std::string fixed(double v, int digits) { return json_number(v, digits); }

// `value` when `known`, else null (a figure the run could not measure).
Json known_or_null(bool known, Json value) { return known ? std::move(value) : Json(nullptr); }

struct Counts {
  int planned = 0, marked = 0, skipped = 0, sprayed = 0;
};
// One panel's counts; its score's `marked` when scored.
Counts counts(const control::PanelResult& panel, const Score* score) {
  Counts c;
  const auto tally = panel.tally();
  c.skipped = tally.skipped;
  c.sprayed = tally.sprayed;
  c.planned = panel.defects.ssize() - c.skipped;
  c.marked = score != nullptr ? score->marked : c.sprayed;
  return c;
}
// Over every panel of the run.
Counts counts(const PredictorRun& r) {
  Counts c;
  for (const PanelRun& p : r.panels) {
    const Counts one = counts(p.result, r.scored ? &p.score : nullptr);
    c.planned += one.planned, c.marked += one.marked, c.skipped += one.skipped, c.sprayed += one.sprayed;
  }
  return c;
}

// The plan made once the panel's motion was known, against what the run did: each
// defect planned feasible was sprayed and each planned out was not (matches_run), and
// how far the planned pulse times were from the actual ones.
struct PlanCheck {
  bool made = false;
  int feasible = 0, infeasible = 0;
  bool matches = true;
  double time_error_max = 0;  // s
};
PlanCheck plan_check(const control::PanelResult& panel) {
  PlanCheck p;
  p.made = panel.planned_at >= 0;
  for (int i = 0; i < panel.defects.ssize() && p.made; ++i) {
    const auto& d = panel.defects[static_cast<std::size_t>(i)];
    if (d.plan == control::PlanVerdict::kNotPlanned) continue;
    const bool feasible = d.plan == control::PlanVerdict::kFeasible;
    (feasible ? p.feasible : p.infeasible) += 1;
    if (feasible != d.sprayed) p.matches = false;
    if (feasible && d.sprayed)
      p.time_error_max = std::max(p.time_error_max, std::abs(to_seconds(d.spray_requested - d.planned_spray)));
  }
  return p;
}

Json plan_json(const control::PanelResult& panel) {
  const PlanCheck p = plan_check(panel);
  if (!p.made) return nullptr;
  Json verdicts = Json::array();
  for (const control::DefectResult& d : panel.defects) {
    // Times from when the plan was made.
    const auto since = [&](Nanos t) { return t >= 0 ? num(to_seconds(t - panel.planned_at)) : Json(nullptr); };
    verdicts.push_back(Json{{"id", d.id},
                            {"verdict", control::to_string(d.plan)},
                            {"planned_spray_s", since(d.planned_spray)},
                            {"spray_s", since(d.sprayed ? d.spray_requested : -1)},
                            {"placement_sigma_mm", num(d.placement_sigma * 1000)}});
  }
  return Json{{"feasible", p.feasible},
              {"infeasible", p.infeasible},
              {"matches_run", p.matches},
              {"spray_time_error_s_max", num(p.time_error_max)},
              {"verdicts", std::move(verdicts)}};
}

// The figures of one predictor's run.
Json ic_json(const control::Intercalibration& ic) {
  const bool has_ic = ic.inliers > 0;
  return Json{{"max_abs", known_or_null(has_ic, vec(ic.max_abs, 100))},
              {"rms", known_or_null(has_ic, vec(ic.rms, 100))},
              {"macro_features", ic.inliers},
              {"status", control::to_string(ic.status)}};
}

// Each panel of the run (one per panel-present episode): its result and its own score.
Json panels_json(const PredictorRun& r) {
  Json out = Json::array();
  for (const PanelRun& p : r.panels) {
    const Counts c = counts(p.result, r.scored ? &p.score : nullptr);
    const bool marked = r.scored && p.score.marked > 0;
    out.push_back(Json{{"id", p.result.panel_id.view()},
                       {"fault", p.result.fault},
                       {"reason", p.result.reason.view()},
                       {"started_s", num(to_seconds(p.result.started))},
                       {"finished_s", p.result.finished > 0 ? num(to_seconds(p.result.finished)) : Json(nullptr)},
                       {"defects", {{"planned", c.planned}, {"marked", c.marked}, {"skipped", c.skipped}, {"sprayed", c.sprayed}}},
                       {"false_sprays", known_or_null(r.scored, p.score.false_sprays)},
                       {"marking_error_mm",
                        {{"max", known_or_null(marked, num(p.score.error_max * 1000))},
                         {"rms", known_or_null(marked, num(p.score.error_rms * 1000))}}},
                       {"plan", plan_json(p.result)},
                       {"intercalibration_cm", ic_json(p.result.intercalibration)}});
  }
  return out;
}

Json run_json(const PredictorRun& r) {
  const Counts c = counts(r);
  Json skipped = Json::array();
  for (std::size_t k = 0; k < r.panels.size(); ++k)
    for (const control::DefectResult& d : r.panels[k].result.defects)
      if (d.skipped != control::SkipReason::kNone)
        skipped.push_back(Json{{"panel", k + 1}, {"id", d.id}, {"reason", control::to_string(d.skipped)}});
  Json per_defect = Json::array();
  for (const auto& d : r.prediction_per_defect) per_defect.push_back(Json{{"id", d.id}, {"abs", vec(d.abs, 1000)}});
  const bool marked = r.scored && r.score.marked > 0, posed = r.pose_samples > 0;
  Json sprays = Json::array();
  for (const auto& s : r.score.sprays)
    sprays.push_back(Json{{"t_s", num(to_seconds(s.time), 4)},
                          {"defect", s.nearest_defect},
                          {"distance_mm", num(s.distance * 1000)},
                          {"hit", s.hit},
                          {"standoff_mm", known_or_null(s.on_panel, num(s.standoff * 1000))},
                          {"open_ms", known_or_null(s.open_for >= 0, num(static_cast<double>(s.open_for) / 1e6))}});
  return Json{
      {"predictor", r.predictor},
      {"defects",
       {{"planned", c.planned}, {"marked", c.marked}, {"skipped", c.skipped}, {"sprayed", c.sprayed}, {"skipped_reasons", skipped}}},
      {"plan", plan_json(r.panel)},
      {"false_sprays", known_or_null(r.scored, r.score.false_sprays)},
      // What a spray was judged by: where it landed on the recorded panel's surface, or
      // (a panel the rig has no surface of) how far its axis passed from each defect.
      {"scored_on", known_or_null(r.scored, std::string(r.score.scored_on == ScoredOn::kSurface ? "surface" : "aim"))},
      {"marking_error_mm",
       {{"max", known_or_null(marked, num(r.score.error_max * 1000))}, {"rms", known_or_null(marked, num(r.score.error_rms * 1000))}}},
      {"prediction_error_mm",
       {{"max_abs", r.prediction_max_abs ? vec(*r.prediction_max_abs, 1000) : Json(nullptr)},
        {"one_frame_ahead_max_abs", vec(r.one_frame_max_abs, 1000)},
        {"per_defect", per_defect}}},
      {"intercalibration_cm", ic_json(r.panel.intercalibration)},
      {"pose_error_mm",
       {{"max", known_or_null(posed, num(r.pose_error_max * 1000))},
        {"rms", known_or_null(posed, num(r.pose_error_rms * 1000))},
        {"samples", r.pose_samples},
        {"missing_mfs_max", known_or_null(r.pose_samples_missing > 0, num(r.pose_error_missing_max * 1000))},
        {"missing_mfs_samples", r.pose_samples_missing},
        {"setup_frame_max", known_or_null(posed, num(r.pose_error_setup_frame_max * 1000))}}},
      {"defect_error_mm",
       {{"max", known_or_null(posed, num(r.defect_error_max * 1000))}, {"rms", known_or_null(posed, num(r.defect_error_rms * 1000))}}},
      {"seconds_per_defect", known_or_null(c.sprayed > 0, num(r.seconds_per_defect))},
      {"deadline_misses", r.deadline_misses},
      {"overruns", r.overruns},
      {"panel", {{"id", r.panel.panel_id.view()}, {"fault", r.panel.fault}, {"reason", r.panel.reason.view()}}},
      // Every panel of the run: the figures above are over all of them (plan,
      // intercalibration_cm and panel: the first's).
      {"episodes", r.episodes},
      {"panels", panels_json(r)},
      {"vision",
       {{"frames", r.vision.frames.load()},
        {"dropped", r.vision.dropped.load()},
        {"poses", r.vision.poses.load()},
        {"skipped", r.frames_skipped},
        {"arm_drawn", r.arm.drawn},
        {"arm_hid_pairs", r.arm.hid_pairs},
        {"arm_hidden_mfs", r.arm.hidden_mfs}}},
      {"peer_late_ticks", r.peer_late_ticks},
      {"sprays", sprays},
      {"faults", r.faults}};
}

// --- plots ------------------------------------------------------------------------
struct Series {
  std::vector<double> t, v;
  cv::Scalar colour;
  std::string label;
};

void plot_panel(cv::Mat& img, const cv::Rect& area, const std::vector<Series>& series, const std::string& title) {
  cv::rectangle(img, area, cv::Scalar(200, 200, 200));
  double t0 = 1e300, t1 = -1e300, v0 = 1e300, v1 = -1e300;
  for (const auto& s : series)
    for (std::size_t i = 0; i < s.t.size(); ++i) {
      t0 = std::min(t0, s.t[i]), t1 = std::max(t1, s.t[i]);
      v0 = std::min(v0, s.v[i]), v1 = std::max(v1, s.v[i]);
    }
  cv::putText(img, title, {area.x + 6, area.y + 16}, cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
  if (t1 <= t0) return;
  if (v1 - v0 < 1e-9) v0 -= 0.5, v1 += 0.5;
  const double pad = 0.08 * (v1 - v0);
  v0 -= pad, v1 += pad;
  auto px = [&](double t, double v) {
    return cv::Point(area.x + 50 + static_cast<int>((t - t0) / (t1 - t0) * (area.width - 60)),
                     area.y + 24 + static_cast<int>((v1 - v) / (v1 - v0) * (area.height - 40)));
  };
  if (v0 < 0 && v1 > 0) cv::line(img, px(t0, 0), px(t1, 0), cv::Scalar(220, 220, 220));
  for (std::size_t k = 0; k < series.size(); ++k) {
    const auto& s = series[k];
    for (std::size_t i = 1; i < s.t.size(); ++i) cv::line(img, px(s.t[i - 1], s.v[i - 1]), px(s.t[i], s.v[i]), s.colour, 1, cv::LINE_AA);
    cv::putText(img, s.label, {area.x + area.width - 150, area.y + 16 + 14 * static_cast<int>(k)}, cv::FONT_HERSHEY_SIMPLEX, 0.4,
                s.colour, 1, cv::LINE_AA);
  }
  cv::putText(img, fixed(v1, 1), {area.x + 2, area.y + 30}, cv::FONT_HERSHEY_SIMPLEX, 0.35, cv::Scalar(80, 80, 80));
  cv::putText(img, fixed(v0, 1), {area.x + 2, area.y + area.height - 14}, cv::FONT_HERSHEY_SIMPLEX, 0.35, cv::Scalar(80, 80, 80));
  cv::putText(img, fixed(t0, 1) + " s", {area.x + 50, area.y + area.height - 2}, cv::FONT_HERSHEY_SIMPLEX, 0.35, cv::Scalar(80, 80, 80));
  cv::putText(img, fixed(t1, 1) + " s", {area.x + area.width - 50, area.y + area.height - 2}, cv::FONT_HERSHEY_SIMPLEX, 0.35,
              cv::Scalar(80, 80, 80));
}

// Fig. 8: the marked defect's estimated, predicted (one frame ahead) and true position
// per axis, in mm relative to its first estimate, and the prediction's error components.
void plot_prediction(const PredictorRun& r, const std::string& path) {
  cv::Mat img(4 * 180, 900, CV_8UC3, cv::Scalar(255, 255, 255));
  const char* axis[3] = {"x (across, CamR)", "y (down, CamR)", "z (depth, CamR)"};
  std::vector<Series> err(3);
  const cv::Scalar ecol[3] = {{200, 0, 0}, {0, 150, 0}, {0, 0, 220}};
  for (int a = 0; a < 3; ++a) {
    Series est{{}, {}, cv::Scalar(200, 0, 0), "estimated"}, pred{{}, {}, cv::Scalar(0, 0, 220), "predicted"},
        tru{{}, {}, cv::Scalar(0, 150, 0), "truth"};
    err[static_cast<std::size_t>(a)] = Series{{}, {}, ecol[a], std::string("error ") + "xyz"[a]};
    for (std::size_t i = 0; i < r.samples.size(); ++i) {
      const auto& s = r.samples[i];
      const double t = to_seconds(s.time);
      est.t.push_back(t), est.v.push_back(s.estimated_CamR(a) * 1000);
      pred.t.push_back(t), pred.v.push_back(s.predicted_CamR(a) * 1000);
      if (i < r.truth_samples.size()) tru.t.push_back(t), tru.v.push_back(r.truth_samples[i].p(a) * 1000);
      err[static_cast<std::size_t>(a)].t.push_back(t);
      err[static_cast<std::size_t>(a)].v.push_back((s.predicted_CamR(a) - s.estimated_CamR(a)) * 1000);
    }
    plot_panel(img, cv::Rect(0, 180 * a, 900, 178), {est, pred, tru}, std::string(axis[a]) + ", mm (" + r.predictor + ")");
  }
  plot_panel(img, cv::Rect(0, 540, 900, 178), err, "predicted - estimated, mm");
  cv::imwrite(path, img);
}

cv::Mat to_bgr(const cv::Mat& grey) {
  cv::Mat out;
  cv::cvtColor(grey, out, cv::COLOR_GRAY2BGR);
  return out;
}

}  // namespace

std::vector<std::string> write_report(const ReplayReport& report, const CellConfig& config, const std::string& out_dir) {
  std::filesystem::create_directories(out_dir);
  std::vector<std::string> files;
  const std::filesystem::path dir(out_dir);
  const PredictorRun& main = report.runs.front();

  // Plots first: the report lists them.
  const std::string fig8 = (dir / "prediction.png").string();
  plot_prediction(main, fig8);
  files.push_back(fig8);
  try {
    // Figs. 5 and 6 on the first frame where the panel's MFs are found, as the cell found them.
    const vision::Recording rec = vision::Recording::open(report.recording);
    const vision::StereoRig rig(vision::load_stereo_calibration(report.calibration.empty() ? config.calibration.stereo : report.calibration));
    std::string type_file;
    for (const auto& p : config.panel_types)
      if (p.name == report.panel_type) type_file = p.file;
    const vision::PanelTypeModel model = vision::load_panel_type(type_file);
    vision::PanelTracker tracker(rig, model, vision::TrackerParams{});
    for (std::size_t i = 0; i < std::min<std::size_t>(rec.size(), 60); ++i) {
      const vision::ReplayFrame f = rec.read(i);
      if (f.dropped) continue;
      const msg::PoseEstimate& e = tracker.process(f.seq, f.time, f.left, f.right);
      if (e.status != msg::TrackStatus::kReinitialised) continue;
      cv::Mat l = to_bgr(f.left), r = to_bgr(f.right), both;
      for (int k = 0; k < e.mfs.ssize(); ++k) {
        const auto& o = e.mfs[static_cast<std::size_t>(k)];
        if (!o.valid) continue;
        const cv::Scalar c(0, 200 - 15 * k, 40 + 20 * k);
        cv::circle(l, cv::Point2d(o.left.x(), o.left.y()), 5, c, 1, cv::LINE_AA);
        cv::putText(l, std::to_string(k + 1), cv::Point2d(o.left.x() + 6, o.left.y() - 6), cv::FONT_HERSHEY_SIMPLEX, 0.4, c);
        const Eigen::Vector3d line = rig.F() * rig.undistort(vision::Camera::kLeft, o.left).homogeneous();
        if (std::abs(line.y()) > 1e-12)
          cv::line(r, cv::Point2d(0, -line.z() / line.y()), cv::Point2d(r.cols, -(line.z() + line.x() * r.cols) / line.y()), c, 1, cv::LINE_AA);
        cv::circle(r, cv::Point2d(o.right.x(), o.right.y()), 5, c, 1, cv::LINE_AA);
      }
      cv::hconcat(l, r, both);
      cv::putText(both, "macro-features (left) and their epipolar lines (right), frame " + std::to_string(f.seq), {8, 18},
                  cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
      const std::string fig5 = (dir / "mf_epipolar.png").string();
      cv::imwrite(fig5, both);
      files.push_back(fig5);
      // Fig. 6: the MF area as the inspection station reconstructed it (through the
      // inter-calibration) and as the marking station estimated it.
      const auto& ic = main.panel.intercalibration;
      if (ic.inliers > 0) {
        const control::PanelJob job =
            read_inspection_record((std::filesystem::path(report.recording) / "inspection.yaml").string(), config.panel_types);
        cv::Mat area = to_bgr(f.left);
        std::vector<cv::Point> rec_pts, est_pts;
        for (std::size_t k = 0; k < std::min(e.mfs.size(), job.mfs_SL.size()); ++k) {
          if (!job.mfs_SL[k].allFinite()) continue;  // not measured at the inspection station
          const Eigen::Vector2d a = rig.project(vision::Camera::kLeft, ic.X_P_SL * job.mfs_SL[k]);
          rec_pts.emplace_back(static_cast<int>(std::lround(a.x())), static_cast<int>(std::lround(a.y())));
          if (e.mfs[k].valid) {
            const Eigen::Vector2d b = rig.project(vision::Camera::kLeft, e.mfs[k].p_CamR);
            est_pts.emplace_back(static_cast<int>(std::lround(b.x())), static_cast<int>(std::lround(b.y())));
          }
        }
        std::vector<cv::Point> hull_rec, hull_est;
        cv::convexHull(rec_pts, hull_rec);
        if (est_pts.size() >= 3) cv::convexHull(est_pts, hull_est);
        cv::polylines(area, hull_rec, true, cv::Scalar(0, 200, 0), 2, cv::LINE_AA);
        if (!hull_est.empty()) cv::polylines(area, hull_est, true, cv::Scalar(0, 0, 255), 1, cv::LINE_AA);
        for (const auto& p : rec_pts) cv::drawMarker(area, p, cv::Scalar(0, 200, 0), cv::MARKER_CROSS, 8);
        for (const auto& p : est_pts) cv::circle(area, p, 4, cv::Scalar(0, 0, 255), 1, cv::LINE_AA);
        cv::putText(area, "MF area: reconstructed (inspection, green) vs estimated (marking, red)", {8, 18},
                    cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
        const std::string fig6 = (dir / "mf_area.png").string();
        cv::imwrite(fig6, area);
        files.push_back(fig6);
      }
      break;
    }
    // The spray points on the frame nearest the last spray.
    if (main.scored && !main.score.sprays.empty() && rec.size() > 0) {
      const Nanos t = main.score.sprays.back().time;
      std::size_t best = 0;
      for (std::size_t i = 0; i < rec.size(); ++i)
        if (std::llabs(rec.entry(i).time - rec.entry(0).time - t) < std::llabs(rec.entry(best).time - rec.entry(0).time - t)) best = i;
      const vision::ReplayFrame f = rec.read(best);
      if (!f.dropped) {
        cv::Mat img = to_bgr(f.right);
        const double fx = rig.calibration().right.K(0, 0);
        for (const auto& s : main.score.sprays) {
          if (!s.on_panel) continue;
          const Eigen::Vector2d p = rig.project(vision::Camera::kRight, s.p_CamR);
          cv::drawMarker(img, cv::Point2d(p.x(), p.y()), s.hit ? cv::Scalar(0, 200, 0) : cv::Scalar(0, 0, 255), cv::MARKER_TILTED_CROSS, 10, 2);
          const int radius = static_cast<int>(std::lround(fx * 0.010 / s.p_CamR.z()));
          cv::circle(img, cv::Point2d(p.x(), p.y()), std::max(radius, 2), cv::Scalar(0, 200, 255), 1, cv::LINE_AA);
        }
        cv::putText(img, "sprays where they landed (x; circle: 10 mm) at their own times", {8, 18}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                    cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
        const std::string sp = (dir / "sprays.png").string();
        cv::imwrite(sp, img);
        files.push_back(sp);
      }
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "markcell: plots of %s: %s\n", report.recording.c_str(), e.what());
  }

  // The command logs (sim/command_log.hpp): can.log in candump -L and valve.log always,
  // serial.log for a serial arm. A previous run's files in the folder go first, so none
  // is left beside this run's.
  for (const char* name : {"can.log", "serial.log", "valve.log", "commands.log"}) std::filesystem::remove(dir / name);
  const auto write_log = [&](const char* name, const std::string& text) {
    const std::string file = (dir / name).string();
    std::ofstream(file) << text;
    files.push_back(file);
  };
  if (!main.command_log.serial.empty()) write_log("serial.log", main.command_log.serial);
  if (!main.command_log.can.empty() || main.command_log.serial.empty()) write_log("can.log", main.command_log.can);
  write_log("valve.log", main.command_log.valve);

  const std::string json = (dir / "report.json").string();
  Json doc{{"scenario", report.scenario},
           {"recording", report.recording},
           {"panel_type", report.panel_type},
           {"calibration", report.calibration},
           {"devices", report.devices},
           // A run stopped by a signal is partial: said first, so no reader takes it for whole.
           {"stopped", report.stopped.empty() ? Json(nullptr) : Json(report.stopped)},
           {"index_problems", report.index_problems}};
  const Json main_run = run_json(main);  // (named: items() does not keep a temporary alive)
  for (const auto& [key, value] : main_run.items()) doc[key] = value;  // the configured predictor's, at the top
  Json predictors = Json::object();
  for (const auto& run : report.runs) predictors[run.predictor] = run_json(run);
  doc["predictors"] = std::move(predictors);
  doc["paper"] = Json{{"intercalibration_cm", {{"max_abs", {1.63, 0.89, 2.01}}, {"rms", {0.86, 0.45, 1.16}}}},
                      {"prediction_error_mm", {{"max_abs", {9.67, 2.0, 2.0}}}},
                      {"seconds_per_defect", {{"door", 3.33}, {"fender", 3.75}}},
                      {"region_diameter_cm", {2, 3}},
                      {"frame_rate_hz", 0.5}};
  if (const auto insp = inspection_figures(report.recording))
    doc["inspection"] = Json{{"macro_features", insp->mfs},
                             {"measured", insp->measured},
                             {"epipolar_px", {{"median", insp->epipolar_median}, {"max", insp->epipolar_max}}},
                             {"triangulation_error_mm", {{"median", insp->error_median_mm}, {"max", insp->error_max_mm}}}};
  else
    doc["inspection"] = nullptr;
  Json plots = Json::array();
  for (const auto& f : files)
    if (f.ends_with(".png")) plots.push_back(std::filesystem::path(f).filename().string());
  doc["plots"] = std::move(plots);
  std::ofstream out(json);
  // Text the rig did not make (a recording's path, index problems) may hold any bytes:
  // replaced, never a report that fails to write.
  out << doc.dump(2, ' ', false, Json::error_handler_t::replace) << "\n";
  out.close();
  files.insert(files.begin(), json);
  return files;
}

std::string report_table(const ReplayReport& report, const std::vector<std::string>& files) {
  std::ostringstream o;
  char line[256];
  if (!report.stopped.empty())
    o << "STOPPED by " << report.stopped << ": a partial run; its figures count only what was done by then\n";
  // Index lines the reader refused are not in the replay: said first, each one.
  if (!report.index_problems.empty()) {
    o << "frames.csv: " << report.index_problems.size() << " line(s) refused, not replayed:\n";
    for (const auto& p : report.index_problems) o << "  " << escape_log(p) << "\n";
  }
  o << "marking (" << report.scenario << ", " << report.panel_type << (report.devices == "simulated" ? "" : "; devices " + report.devices)
    << "):\n";
  std::snprintf(line, sizeof line, "  %-38s", "");
  o << line;
  for (const auto& r : report.runs) {
    std::snprintf(line, sizeof line, "%-16s", r.predictor.c_str());
    o << line;
  }
  o << "paper\n";
  auto row = [&](const char* name, auto get, const char* paper) {
    std::snprintf(line, sizeof line, "  %-38s", name);
    o << line;
    for (const auto& r : report.runs) {
      // (padded by hand: GCC 12's -O3 for aarch64 warns, wrongly, of a null destination
      // for snprintf into `line` here)
      const std::string cell = get(r);
      o << cell << std::string(cell.size() < 16 ? 16 - cell.size() : 0, ' ');
    }
    o << paper << "\n";
  };
  row("panels handled / episodes", [](const PredictorRun& r) {
    return std::to_string(r.panels.size()) + "/" + std::to_string(r.episodes);
  }, "-");
  row("defects marked / planned / skipped", [](const PredictorRun& r) {
    const Counts c = counts(r);
    return std::to_string(c.marked) + "/" + std::to_string(c.planned) + "/" + std::to_string(c.skipped);
  }, report.panel_type == "fender" ? "4 in 15 s" : "3 in 10 s");
  row("plan: feasible / matches the run", [](const PredictorRun& r) {
    const PlanCheck p = plan_check(r.panel);
    return p.made ? std::to_string(p.feasible) + "/" + std::to_string(p.feasible + p.infeasible) + " " + (p.matches ? "yes" : "NO")
                  : std::string("-");
  }, "-");
  row("false sprays", [](const PredictorRun& r) { return r.scored ? std::to_string(r.score.false_sprays) : std::string("-"); }, "-");
  row("scored on", [](const PredictorRun& r) {
    return r.scored ? std::string(r.score.scored_on == ScoredOn::kSurface ? "surface" : "aim") : std::string("-");
  }, "-");
  row("marking error max / rms, mm", [](const PredictorRun& r) {
    return r.scored && r.score.marked > 0 ? fixed(r.score.error_max * 1000, 1) + " / " + fixed(r.score.error_rms * 1000, 1) : std::string("-");
  }, "region 20-30 mm");
  row("seconds per defect", [](const PredictorRun& r) { return r.seconds_per_defect > 0 ? fixed(r.seconds_per_defect, 2) : std::string("-"); },
      report.panel_type == "fender" ? "3.75" : "3.33");
  row("prediction error max |x y z|, mm", [](const PredictorRun& r) {
    return r.prediction_max_abs ? fixed(r.prediction_max_abs->x() * 1000, 1) + " " + fixed(r.prediction_max_abs->y() * 1000, 1) + " " +
                                      fixed(r.prediction_max_abs->z() * 1000, 1)
                                : std::string("-");
  }, "9.67 2 2");
  row("inter-cal max |x y z|, cm", [](const PredictorRun& r) {
    const auto& m = r.panel.intercalibration.max_abs;
    return r.panel.intercalibration.inliers > 0 ? fixed(m.x() * 100, 2) + " " + fixed(m.y() * 100, 2) + " " + fixed(m.z() * 100, 2) : std::string("-");
  }, "1.63 0.89 2.01");
  row("inter-cal rms x y z, cm", [](const PredictorRun& r) {
    const auto& m = r.panel.intercalibration.rms;
    return r.panel.intercalibration.inliers > 0 ? fixed(m.x() * 100, 2) + " " + fixed(m.y() * 100, 2) + " " + fixed(m.z() * 100, 2) : std::string("-");
  }, "0.86 0.45 1.16");
  row("panel pose error max / rms, mm", [](const PredictorRun& r) {
    return r.pose_samples > 0 ? fixed(r.pose_error_max * 1000, 1) + " / " + fixed(r.pose_error_rms * 1000, 1) : std::string("-");
  }, "-");
  row("  with MFs missing, max, mm", [](const PredictorRun& r) {
    return r.pose_samples_missing > 0 ? fixed(r.pose_error_missing_max * 1000, 1) : std::string("-");
  }, "-");
  row("tracked defect error max / rms, mm", [](const PredictorRun& r) {
    return r.pose_samples > 0 ? fixed(r.defect_error_max * 1000, 1) + " / " + fixed(r.defect_error_rms * 1000, 1) : std::string("-");
  }, "-");
  row("frames / poses / dropped", [](const PredictorRun& r) {
    return std::to_string(r.vision.frames.load()) + "/" + std::to_string(r.vision.poses.load()) + "/" + std::to_string(r.vision.dropped.load());
  }, "0.5 Hz");
  row("deadline misses", [](const PredictorRun& r) { return std::to_string(r.deadline_misses); }, "-");
  for (const auto& r : report.runs)
    for (const PanelRun& p : r.panels)
      for (const control::DefectResult& d : p.result.defects)
        if (d.skipped != control::SkipReason::kNone)
          o << "  [" << r.predictor << "] panel " << p.result.panel_id.c_str() << " defect " << d.id
            << " skipped: " << control::to_string(d.skipped) << "\n";
  if (const auto insp = inspection_figures(report.recording))
    o << "inspection station: " << insp->measured << " of " << insp->mfs << " MFs measured in the scanner's pair; "
      << "error against the truth median " << fixed(insp->error_median_mm, 2) << " / max " << fixed(insp->error_max_mm, 2)
      << " mm; epipolar residual median " << fixed(insp->epipolar_median, 2) << " / max " << fixed(insp->epipolar_max, 2)
      << " px\n";
  o << "\ntiming (" << report.runs.front().predictor << " run, " << (report.devices == "simulated" ? "simulated" : "real")
    << " clock):\n" << report.runs.front().timing_report;
  o << "\nwrote:\n";
  for (const auto& f : files) o << "  " << f << "\n";
  return o.str();
}

}  // namespace markcell::rig
