// Films a run on a second thread from copied states (FrameRecorder, render.h).
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <exception>
#include <future>
#include <mutex>
#include <thread>

#include "vcsim/render.h"

namespace vcsim {

struct FrameRecorder::Shared {
  static constexpr std::size_t kQueue = 4;
  struct Job {
    FrameSnapshot snap;
    CArmPose pose;
    int index = 0;
  };
  ImageChainSettings chain;
  std::filesystem::path dir;
  int size = 0;
  std::mutex m;
  std::condition_variable cv;
  std::deque<Job> queue;
  int busy = 0;
  bool closed = false, failed = false;
  double render_s = 0.0;
  std::exception_ptr error;
  std::thread worker;

  void run(SimFluoroscopy& fluoro) {
    std::vector<std::uint8_t> img;
    for (;;) {
      Job job;
      {
        std::unique_lock lock(m);
        cv.wait(lock, [&] { return !queue.empty() || closed; });
        if (queue.empty()) return;
        job = std::move(queue.front());
        queue.pop_front();
        ++busy;
      }
      cv.notify_all();
      const double t0 = now_us();
      ImageChainSettings c = chain;
      c.seed = static_cast<std::uint64_t>(job.index + 1);
      fluoro.frame(job.snap, job.pose, c, img);
      char name[32];
      std::snprintf(name, sizeof name, "frame_%05d.png", job.index);
      write_png_grey((dir / name).string(), img, size, size);
      {
        std::lock_guard lock(m);
        --busy;
        render_s += (now_us() - t0) * 1e-6;
      }
      cv.notify_all();
    }
  }
  void rethrow() {
    std::exception_ptr e;
    {
      std::lock_guard lock(m);
      e = error;
    }
    if (e) std::rethrow_exception(e);
  }
  void close() {
    {
      std::lock_guard lock(m);
      closed = true;
    }
    cv.notify_all();
    if (worker.joinable()) worker.join();
  }
};

FrameRecorder::FrameRecorder(const SimModel& model, int size, BeamEnergy energy,
                             ImageChainSettings chain, std::filesystem::path dir)
    : s_(std::make_unique<Shared>()) {
  Shared& s = *s_;
  s.chain = chain;
  s.dir = std::move(dir);
  s.size = size;
  std::promise<void> ready;
  auto started = ready.get_future();
  s.worker = std::thread([&s, &model, size, energy, &ready] {
    bool signalled = false;  // after this, `ready` (the constructor's) is gone
    try {
      // The GL context is current on the thread that draws; the model's anatomy and instrument
      // specs, read here, do not change during the run.
      HeadlessGlContext gl;
      SimFluoroscopy fluoro(model, size, energy);
      signalled = true;
      ready.set_value();
      s.run(fluoro);
    } catch (...) {
      std::lock_guard lock(s.m);
      if (!s.error) s.error = std::current_exception();
      s.failed = true;
      s.cv.notify_all();
      if (!signalled) ready.set_value();
    }
  });
  started.wait();
  try {
    s.rethrow();
  } catch (...) {
    // The worker has failed and is ending: join it before the error leaves the constructor (a
    // joinable std::thread destroyed during the unwinding would terminate the program).
    s.close();
    throw;
  }
}

FrameRecorder::~FrameRecorder() {
  s_->close();
}

void FrameRecorder::push(FrameSnapshot snap, const CArmPose& pose) {
  Shared& s = *s_;
  std::unique_lock lock(s.m);
  s.cv.wait(lock, [&] { return s.queue.size() < Shared::kQueue || s.failed; });
  if (s.failed) {
    lock.unlock();
    s.rethrow();
  }
  s.queue.push_back({std::move(snap), pose, submitted_++});
  s.cv.notify_all();
}

void FrameRecorder::finish() {
  Shared& s = *s_;
  {
    std::unique_lock lock(s.m);
    s.cv.wait(lock, [&] { return (s.queue.empty() && s.busy == 0) || s.failed; });
  }
  s.rethrow();
}

double FrameRecorder::render_seconds() const {
  std::lock_guard lock(s_->m);
  return s_->render_s;
}

CArmPose scenario_pose(const Scenario& sc) {
  CArmPose pose;
  pose.primary_deg = sc.fluoro.primary_deg;
  pose.secondary_deg = sc.fluoro.secondary_deg;
  pose.fov = sc.fluoro.fov_mm * 1e-3;
  try {
    pose.validate(sc.source);
  } catch (const InputError& e) {
    throw InputError(sc.source, "fluoroscopy." + e.field(), e.what());
  }
  return pose;
}

RunFilm::RunFilm(const SimModel& model, FrameRecorder& recorder)
    : recorder_(recorder),
      pose_(scenario_pose(model.scenario)),
      home_(left_coronary_centre(model.tree)),
      frame_dt_(1.0 / model.scenario.fluoro.fps),
      follow_tip_(model.scenario.fluoro.follow_tip) {
  pose_.isocentre = home_;
}

void RunFilm::after_step(const Simulator& sim) {
  if (sim.time() < next_frame_ - 1e-9) return;
  if (follow_tip_) {
    int lead = 0;
    for (int i = 1; i < sim.num_instruments(); ++i)
      if (sim.depth(i) > sim.depth(lead)) lead = i;
    const Vec3 tip = sim.tip(lead);
    const Vec3 want = (tip - home_).norm() > 0.3 * pose_.fov ? tip : home_;
    if ((want - pose_.isocentre).norm() > 0.3 * pose_.fov) pose_.isocentre = want;
  }
  recorder_.push(snapshot(sim), pose_);
  poses_.push_back(pose_);
  next_frame_ += frame_dt_;
}

}  // namespace vcsim
