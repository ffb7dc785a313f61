#pragma once
// Recordings of stereo frames (format: vision/RECORDING.md): a writer, and a frame
// source that replays them, turning every bad frame into a reported dropped frame.
//
// Reading and decoding PNG files allocates: the frame source stands in for the cameras
// (it is a device twin, like the cameras' own receive threads), not for the controller.
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "markcell/common/time.hpp"

namespace markcell::vision {

class RecordingError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct RecordingManifest {
  std::string station = "marking";
  std::string panel_type;
  double frame_rate_hz = 0;
  int image_width = 0;
  int image_height = 0;
  std::string calibration;  // relative to the recording folder
  bool has_truth = false;
  bool has_defects = false;
  std::optional<std::uint64_t> seed;
  std::string scenario;
  // The program that made it, when it says (`markcell sim` for the rig's own): the replay
  // draws its simulated arm only into the rig's own recordings.
  std::string generator;
  // The panel's surface as a triangle mesh (STL, OBJ, PLY; relative to the recording
  // folder, inside it), in the panel frame of truth.csv, and its unit: the rig scores
  // sprays on it. Empty: no surface known, sprays are scored on the aim alone.
  std::string panel_mesh;
  double panel_mesh_metres_per_unit = 1.0;
  // The macro-features' true positions in the panel frame (metres), in the panel type's
  // order, when the recording's maker knows them: the report places each panel frame P
  // with them. At most 64.
  std::vector<Eigen::Vector3d> macro_features_Panel;
};

struct IndexEntry {
  std::uint64_t seq = 0;
  Nanos time = 0;
  std::string left;
  std::string right;
  int line = 0;  // in frames.csv
};

struct TruthPose {
  std::uint64_t seq = 0;
  Nanos time = 0;
  Eigen::Isometry3d X_CamR_Panel = Eigen::Isometry3d::Identity();
};

struct TruthDefect {
  int id = 0;
  Eigen::Vector3d p_Panel = Eigen::Vector3d::Zero();
  double radius = 0;
};

class RecordingWriter {
 public:
  // Creates the folder (it must not hold a recording already) and writes the manifest
  // when closed. Destroyed by an exception (a write failed, a stop was asked for) it
  // writes nothing more: without recording.yaml the folder is no recording, rather than
  // a shorter one that looks whole.
  RecordingWriter(std::string folder, RecordingManifest manifest);
  ~RecordingWriter();
  void add(std::uint64_t seq, Nanos time, const cv::Mat& left, const cv::Mat& right);
  void add_truth(std::uint64_t seq, Nanos time, const Eigen::Isometry3d& X_CamR_Panel);
  void set_defects(const std::vector<TruthDefect>& defects);
  void close();  // writes recording.yaml, truth.csv and defects.csv; idempotent
  const std::string& folder() const { return folder_; }

 private:
  std::string folder_;
  RecordingManifest manifest_;
  std::vector<IndexEntry> index_;
  std::vector<TruthPose> truth_;
  std::vector<TruthDefect> defects_;
  bool closed_ = false;
  int uncaught_at_start_ = 0;
};

// What the frame source hands out: both images, or why the frame was dropped.
struct ReplayFrame {
  std::uint64_t seq = 0;
  Nanos time = 0;
  std::size_t index = 0;  // position in frames.csv (0-based, header excluded)
  cv::Mat left, right;    // CV_8UC1
  bool dropped = false;
  std::string problem;    // when dropped: which frame, which image, what is wrong
};

class Recording {
 public:
  // Reads and checks the manifest and the index; throws RecordingError naming the file
  // and key (or line) when the recording cannot be used at all.
  static Recording open(const std::string& folder);

  const std::string& folder() const { return folder_; }
  const RecordingManifest& manifest() const { return manifest_; }
  std::string calibration_path() const;
  std::size_t size() const { return index_.size(); }
  const IndexEntry& entry(std::size_t i) const { return index_[i]; }
  // Index lines that could not be read (reported, not fatal), e.g. "frames.csv:5: ...".
  const std::vector<std::string>& index_problems() const { return index_problems_; }
  // Reads frame i; never throws for a bad frame: it comes back dropped, with the reason.
  ReplayFrame read(std::size_t i) const;
  const std::vector<TruthPose>& truth() const { return truth_; }
  const std::vector<TruthDefect>& defects() const { return defects_; }

 private:
  std::string folder_;
  RecordingManifest manifest_;
  std::vector<IndexEntry> index_;
  std::vector<std::string> index_problems_;
  std::vector<TruthPose> truth_;
  std::vector<TruthDefect> defects_;
};

}  // namespace markcell::vision
