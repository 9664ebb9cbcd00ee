// The session's film (film.h): images kept by the window's thread, encoded as PNGs by a worker.
#include "film.h"

#include <algorithm>
#include <cstdio>
#include <string>

#include "vcsim/render.h"

namespace vcsim::trainer {

namespace fs = std::filesystem;

SessionFilm::SessionFilm(fs::path frames_dir, int size) : dir_(std::move(frames_dir)), size_(size) {
  fs::create_directories(dir_);
  // Frames of an earlier session in the same folder would mix with this one's (as `vcsim run`).
  for (const auto& e : fs::directory_iterator(dir_))
    if (e.path().extension() == ".png") fs::remove(e.path());
  worker_ = std::thread([this] { run(); });
}

SessionFilm::~SessionFilm() {
  {
    std::lock_guard lock(m_);
    closed_ = true;
  }
  cv_.notify_all();
  if (worker_.joinable()) worker_.join();
}

fs::path SessionFilm::file_name(int k) const {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%05d.png", k);
  return dir_ / name;
}

void SessionFilm::run() {
  for (;;) {
    Job job;
    {
      std::unique_lock lock(m_);
      cv_.wait(lock, [&] { return !queue_.empty() || closed_; });
      if (queue_.empty()) return;
      job = std::move(queue_.front());
      queue_.pop_front();
      busy_ = true;
    }
    cv_.notify_all();
    std::exception_ptr err;
    try {
      write_png_grey(file_name(job.file).string(), job.image, size_, size_);
    } catch (...) {
      err = std::current_exception();
    }
    {
      std::lock_guard lock(m_);
      busy_ = false;
      if (err && !error_) error_ = err;
    }
    cv_.notify_all();
  }
}

bool SessionFilm::due(double time, bool key) const {
  return key || frames_.empty() || time >= frames_.back().time + kEvery - 1e-9;
}

void SessionFilm::keep(std::span<const std::uint8_t> image, double time, const CArmPose& pose) {
  // The same state shown again (a held image kept twice): one frame is enough.
  if (!frames_.empty() && time <= frames_.back().time + 1e-12) return;
  const int file = next_file_++;
  frames_.push_back({time, pose, file});
  Job job{file, std::vector<std::uint8_t>(image.begin(), image.end())};
  std::unique_lock lock(m_);
  cv_.wait(lock, [&] { return queue_.size() < kQueue; });
  queue_.push_back(std::move(job));
  lock.unlock();
  cv_.notify_all();
}

void SessionFilm::rewound(double time) {
  while (!frames_.empty() && frames_.back().time > time + 1e-9) {
    dropped_.push_back(frames_.back().file);
    frames_.pop_back();
  }
}

void SessionFilm::finish(std::vector<double>& times, std::vector<CArmPose>& poses) {
  {
    std::unique_lock lock(m_);
    cv_.wait(lock, [&] { return queue_.empty() && !busy_; });
    if (error_) std::rethrow_exception(error_);
  }
  for (int f : dropped_) fs::remove(file_name(f));
  dropped_.clear();
  // Files were numbered in the order kept; the survivors keep that order, so renaming each to
  // its place (never above its number) overwrites nothing still to be renamed.
  times.clear();
  poses.clear();
  for (std::size_t k = 0; k < frames_.size(); ++k) {
    Frame& fr = frames_[k];
    const int want = static_cast<int>(k);
    if (fr.file != want) {
      fs::rename(file_name(fr.file), file_name(want));
      fr.file = want;
    }
    times.push_back(fr.time);
    poses.push_back(fr.pose);
  }
  next_file_ = static_cast<int>(frames_.size());
}

}  // namespace vcsim::trainer
