#pragma once
// The pose log: what the tracker made of every frame pair, for anyone who wants to check
// it against their own truth without decoding arm set-points from commands.log.
//
//   poses.csv      one row per frame pair: status, the panel's pose X_CamR_P, the MFs it
//                  rests on, the rigid fit's residual
//   mf_tracks.csv  one row per frame pair and macro-feature: where it was seen in both
//                  views and whether the pose used it
//
// The columns are specified in vision/RECORDING.md ("The pose log"). The vision task
// hands its estimates over through a queue (Cell::enable_pose_log); the service loop, a
// thread that is never a lane, writes them here. Numbers are printed with fixed decimals,
// so the same replay gives the same bytes. Under `markcell run` both files are appended
// to across restarts and rotated (FILE -> FILE.1, the previous .1 dropped) once one
// passes its size limit.
#include <cstdint>
#include <string>

#include "markcell/msg/pose_estimate.hpp"

namespace markcell::host {

class PoseLog {
 public:
  enum class Mode { kTruncate, kAppend };
  // Opens FOLDER/poses.csv and FOLDER/mf_tracks.csv (the folder must exist), writing the
  // header of each file that is new or empty. `rotate_bytes`: 0 for no rotation. Throws
  // naming the file that could not be opened.
  PoseLog(const std::string& folder, Mode mode, std::uint64_t rotate_bytes);
  PoseLog(const PoseLog&) = delete;
  PoseLog& operator=(const PoseLog&) = delete;
  ~PoseLog();

  // One frame pair's rows. False when a file could not be written (disk full): the rows
  // are lost, counted in failed(); the cell goes on.
  // Each file's rows of a frame pair go in one write(2), all or nothing.
  bool write(const msg::PoseEstimate& e);
  std::uint64_t rows() const { return rows_; }      // frame pairs written
  std::uint64_t failed() const { return failed_; }  // frame pairs lost to a write error
  std::uint64_t rotations() const { return rotations_; }
  const std::string& poses_path() const { return poses_.path; }
  const std::string& tracks_path() const { return tracks_.path; }

  static constexpr const char* kPosesHeader =
      "seq,time_ns,status,reference_time_ns,x,y,z,qw,qx,qy,qz,tracked,inliers,rms_m,reason\n";
  static constexpr const char* kTracksHeader = "seq,time_ns,mf,state,uL,vL,uR,vR\n";

 private:
  struct File {
    std::string path;
    const char* header = nullptr;
    int fd = -1;
    std::uint64_t bytes = 0;
  };
  void open(File& file, Mode mode);
  bool put(File& file, const char* text, std::size_t n);
  void rotate(File& file);
  File poses_, tracks_;
  std::uint64_t rotate_bytes_ = 0;
  std::uint64_t rows_ = 0, failed_ = 0, rotations_ = 0;
};

}  // namespace markcell::host
