// The session's film (internal to apps/trainer): the fluoroscopy images the window displayed,
// kept at a modest rate so that the session report (docs/assessment.md) can show key frames.
// Written as DIR/frames/frame_%05d.png by a worker thread (PNG encoding off the window's thread)
// with each frame's simulated time and C-arm pose for DIR/frames.csv, in the format of `vcsim
// run`'s film. At most kQueue images wait in memory; the rest are on disk.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <filesystem>
#include <mutex>
#include <span>
#include <thread>
#include <vector>

#include "vcsim/core.h"
#include "vcsim/render.h"

namespace vcsim::trainer {

class SessionFilm {
 public:
  // One image a second of simulated time while the beam is on (docs/trainer.md).
  static constexpr double kEvery = 1.0;
  // Images waiting for the writer at most (512 px: 256 kB each).
  static constexpr std::size_t kQueue = 8;

  // Films into `frames_dir` (created; PNGs of an earlier session there are removed) images of
  // size x size grey pixels.
  SessionFilm(std::filesystem::path frames_dir, int size);
  ~SessionFilm();
  SessionFilm(const SessionFilm&) = delete;
  SessionFilm& operator=(const SessionFilm&) = delete;

  // True when an image shown at simulated time `time` (s) is to be kept: kEvery after the last
  // kept, or at once when `key` (a key moment: an assessment event, an injection's end...).
  bool due(double time, bool key) const;
  // Keeps a copy of `image` (row 0 at the top), shown at `time` (s) through the C-arm `pose`
  // (angles, field and the table's pan as the trainee had them). Waits only while kQueue images
  // wait for the writer.
  void keep(std::span<const std::uint8_t> image, double time, const CArmPose& pose);
  // The state went back to `time` (a rewind, a restart): the frames after it are dropped (their
  // files removed by finish()), so that the film is of the steps that led to the final state.
  void rewound(double time);
  // Waits for the writer, removes the dropped frames' files and numbers the rest in order of
  // time (frame_00000.png...). Returns the frames' times (s) and C-arm poses, one per file.
  // Throws what the writer threw (a PNG that could not be written).
  void finish(std::vector<double>& times, std::vector<CArmPose>& poses);

  int kept() const { return static_cast<int>(frames_.size()); }  // frames kept (not dropped)
  double last_time() const { return frames_.empty() ? -1.0 : frames_.back().time; }

 private:
  struct Frame {
    double time;
    CArmPose pose;
    int file;  // index in the writer's numbering
  };
  struct Job {
    int file;
    std::vector<std::uint8_t> image;
  };
  void run();
  std::filesystem::path file_name(int k) const;

  std::filesystem::path dir_;
  int size_;
  std::vector<Frame> frames_;  // kept, in order of time
  std::vector<int> dropped_;   // files of frames a rewind dropped
  int next_file_ = 0;
  std::mutex m_;
  std::condition_variable cv_;
  std::deque<Job> queue_;
  bool busy_ = false, closed_ = false;
  std::exception_ptr error_;
  std::thread worker_;
};

}  // namespace vcsim::trainer
