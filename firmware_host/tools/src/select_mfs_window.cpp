#include "markcell/tools/select_mfs_window.hpp"

#include <cstdio>
#include <cstdlib>
#include <stdexcept>

#include <opencv2/highgui.hpp>
#include <opencv2/imgproc.hpp>

#include "markcell/vision/panel_tracker.hpp"

namespace markcell::host {

namespace {

constexpr double kGrabRadiusPx = 8.0;  // a press this close to an MF grabs it

struct Selection {
  const cv::Mat* gray = nullptr;
  int snap_radius = 0;
  std::ostream* log = nullptr;
  std::vector<Eigen::Vector2d> mfs;
  std::vector<vision::MfKind> kinds;  // one per MF
  int selected = -1;
  int dragging = -1;
  Eigen::Vector2d drag_from = Eigen::Vector2d::Zero();
  std::string message = "click on a corner or inside a hole to add a macro-feature";
  bool dirty = true;

  int nearest(const Eigen::Vector2d& p) const {
    int best = -1;
    double best_d = kGrabRadiusPx;
    for (std::size_t i = 0; i < mfs.size(); ++i) {
      const double d = (mfs[i] - p).norm();
      if (d <= best_d) best = static_cast<int>(i), best_d = d;
    }
    return best;
  }
  void say(const std::string& text) {
    message = text;
    *log << text << std::endl;
  }
  static std::string px(double d) {
    char b[32];
    std::snprintf(b, sizeof b, "%.2f px", d);
    return b;
  }
  static std::string at(const Eigen::Vector2d& p) {
    char b[64];
    std::snprintf(b, sizeof b, "(%.2f, %.2f)", p.x(), p.y());
    return b;
  }
  void press(const Eigen::Vector2d& p) {
    if (const int near = nearest(p); near >= 0) {
      selected = dragging = near;
      drag_from = mfs[static_cast<std::size_t>(near)];
      return;
    }
    if (mfs.size() >= static_cast<std::size_t>(msg::kMaxMacroFeatures)) {
      say("no more than " + std::to_string(msg::kMaxMacroFeatures) + " macro-features");
      return;
    }
    const vision::SnapResult r = vision::snap_macro_feature(*gray, p, snap_radius);
    if (!r.ok()) {
      say(r.problem + ": not added");
      return;
    }
    mfs.push_back(r.p);
    kinds.push_back(r.kind);
    selected = static_cast<int>(mfs.size()) - 1;
    say("MF " + std::to_string(mfs.size()) + " (" + std::string(vision::to_string(r.kind)) + ") added at " + at(r.p) + ", " +
        px(r.moved_px) + " from the click");
  }
  void release(const Eigen::Vector2d& p) {
    if (dragging < 0) return;
    auto& mf = mfs[static_cast<std::size_t>(dragging)];
    if ((p - drag_from).norm() > 1.0) {
      if (const vision::SnapResult r = vision::snap_macro_feature(*gray, p, snap_radius); r.ok()) {
        mf = r.p;
        kinds[static_cast<std::size_t>(dragging)] = r.kind;
        say("MF " + std::to_string(dragging + 1) + " (" + std::string(vision::to_string(r.kind)) + ") moved to " + at(r.p) +
            ", " + px(r.moved_px) + " from the release");
      } else {
        mf = drag_from;
        say(r.problem + ": MF " + std::to_string(dragging + 1) + " stays at " + at(drag_from));
      }
    } else {
      mf = drag_from;
      say("MF " + std::to_string(dragging + 1) + " selected");
    }
    dragging = -1;
  }
  void remove_selected() {
    if (selected < 0 || selected >= static_cast<int>(mfs.size())) {
      say("no macro-feature selected");
      return;
    }
    mfs.erase(mfs.begin() + selected);
    kinds.erase(kinds.begin() + selected);
    say("MF " + std::to_string(selected + 1) + " deleted; " + std::to_string(mfs.size()) + " left");
    selected = mfs.empty() ? -1 : static_cast<int>(mfs.size()) - 1;
  }
};

void on_mouse(int event, int x, int y, int flags, void* user) {
  auto& s = *static_cast<Selection*>(user);
  const Eigen::Vector2d p(x, y);
  if (event == cv::EVENT_LBUTTONDOWN) s.press(p);
  else if (event == cv::EVENT_MOUSEMOVE && s.dragging >= 0 && (flags & cv::EVENT_FLAG_LBUTTON) != 0)
    s.mfs[static_cast<std::size_t>(s.dragging)] = p;
  else if (event == cv::EVENT_LBUTTONUP) s.release(p);
  else return;
  s.dirty = true;
}

void draw(const Selection& s, cv::Mat& canvas) {
  cv::cvtColor(*s.gray, canvas, cv::COLOR_GRAY2BGR);
  for (std::size_t i = 0; i < s.mfs.size(); ++i) {
    const cv::Point c(static_cast<int>(std::lround(s.mfs[i].x())), static_cast<int>(std::lround(s.mfs[i].y())));
    const cv::Scalar colour = static_cast<int>(i) == s.selected ? cv::Scalar(0, 255, 255) : cv::Scalar(0, 220, 0);
    if (i < s.kinds.size() && s.kinds[i] == vision::MfKind::kHole) cv::drawMarker(canvas, c, colour, cv::MARKER_CROSS, 12, 1);
    else cv::circle(canvas, c, 6, colour, 1, cv::LINE_AA);
    cv::putText(canvas, std::to_string(i + 1), c + cv::Point(8, -8), cv::FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv::LINE_AA);
  }
  cv::rectangle(canvas, cv::Rect(0, 0, canvas.cols, 36), cv::Scalar(0, 0, 0), cv::FILLED);
  cv::putText(canvas, "click: add  drag: move  d: delete selected  s: save  q: quit", cv::Point(6, 14),
              cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar(255, 255, 255), 1, cv::LINE_AA);
  cv::putText(canvas, s.message, cv::Point(6, 30), cv::FONT_HERSHEY_SIMPLEX, 0.42, cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
}

}  // namespace

std::optional<std::vector<vision::MfPick>> select_mfs_window(const cv::Mat& reference_left, const std::string& title,
                                                              int snap_radius, std::ostream& log) {
  const char* display = std::getenv("DISPLAY");
  if (display == nullptr || *display == '\0')
    throw std::runtime_error("no display to open the window on (DISPLAY is not set): run it on the cell's screen, under "
                             "Xvfb, or give the MFs with --mf X,Y");
  Selection s;
  s.gray = &reference_left;
  s.snap_radius = snap_radius;
  s.log = &log;
  cv::namedWindow(title, cv::WINDOW_AUTOSIZE | cv::WINDOW_GUI_NORMAL);
  cv::setMouseCallback(title, on_mouse, &s);
  cv::Mat canvas;
  log << "window '" << title << "' open" << std::endl;
  for (;;) {
    if (s.dirty) {
      draw(s, canvas);
      cv::imshow(title, canvas);
      s.dirty = false;
    }
    const int key = cv::waitKeyEx(30);  // the GUI's events, a bounded wait each
    if (cv::getWindowProperty(title, cv::WND_PROP_AUTOSIZE) < 0) {  // closed by its window manager
      log << "window closed: nothing saved" << std::endl;
      return std::nullopt;
    }
    if (key < 0) continue;
    const int k = key & 0xFFFF;
    if (k == 'q' || k == 27) {
      cv::destroyWindow(title);
      log << "quit: nothing saved" << std::endl;
      return std::nullopt;
    }
    if (k == 'd' || k == 'x' || k == 0xFFFF /* Delete */ || k == 8 || k == 0xFF08 /* BackSpace */) {
      s.remove_selected();
      s.dirty = true;
    } else if (k == 's') {
      if (s.mfs.size() < 3) {
        s.say("at least 3 macro-features are needed to save (" + std::to_string(s.mfs.size()) + " so far)");
        s.dirty = true;
        continue;
      }
      cv::destroyWindow(title);
      log << "saved " << s.mfs.size() << " macro-features" << std::endl;
      std::vector<vision::MfPick> picks;
      for (std::size_t i = 0; i < s.mfs.size(); ++i)
        picks.push_back({s.mfs[i], s.kinds[i] == vision::MfKind::kHole ? vision::MfKindRequest::kHole : vision::MfKindRequest::kCorner});
      return picks;
    }
  }
}

}  // namespace markcell::host
