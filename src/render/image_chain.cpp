// The image chain after readback: quantum noise on the transmitted photons, a little correlation
// blur, log, window/level, gamma, vignetting and circular collimation -> 8-bit grey. CPU, one
// pass per stage; deterministic for a seed.
#include <algorithm>
#include <cmath>
#include <random>
#include <thread>

#include "vcsim/render.h"

namespace vcsim {

void ImageChainSettings::validate(const std::string& source) const {
  require_nonnegative(dose, source, "dose");
  if (dose > 1e9) throw InputError(source, "dose", "expected at most 1e9 photons per pixel");
  require_finite(window, source, "window");
  require_finite(level, source, "level");
  require_in_range(gamma, 0.0, 5.0, source, "gamma");
  require_nonnegative(blur_sigma_px, source, "blur_sigma_px");
  if (blur_sigma_px > 3.0) throw InputError(source, "blur_sigma_px", "expected at most 3 px");
  require_nonnegative(vignetting, source, "vignetting");
  if (vignetting >= 1.0) throw InputError(source, "vignetting", "expected a fraction below 1");
  require_in_range(collimation, 0.0, 2.0, source, "collimation");
}

namespace {

// An approximately standard normal sample from one 64-bit draw: the sum of four 16-bit uniforms
// (Irwin-Hall, variance 4/12) rescaled. Its tails stop at 3.46 sigma, which an image cannot show,
// and it costs a fraction of Box-Muller's log, sqrt and sine.
inline float normal_approx(std::mt19937_64& rng) {
  const std::uint64_t x = rng();
  const auto sum =
      static_cast<float>((x & 0xffffu) + ((x >> 16) & 0xffffu) + ((x >> 32) & 0xffffu) + (x >> 48));
  constexpr float kScale = 1.7320508f / 65536.0f;  // sqrt(3) / 2^16
  return (sum - 2.0f * 65535.0f) * kScale;
}

// Runs f(row_begin, row_end) over [0, n) rows on up to two threads (the per-pixel stages are
// independent; a frame must fit a fluoroscopy frame period).
template <typename F>
void parallel_rows(std::size_t n, F&& f) {
  const unsigned hw = std::thread::hardware_concurrency();
  if (hw < 2 || n < 64) {
    f(0, n);
    return;
  }
  std::thread t([&] { f(n / 2, n); });
  f(0, n / 2);
  t.join();
}

// Value at fraction q of the sorted sample (partial sort of a copy).
float percentile(std::vector<float> v, double q) {
  if (v.empty()) return 0.0f;
  const auto k = static_cast<std::ptrdiff_t>(q * static_cast<double>(v.size() - 1));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[static_cast<std::size_t>(k)];
}

}  // namespace

void image_chain(std::span<const float> p, int size, const ImageChainSettings& s,
                 std::vector<std::uint8_t>& out) {
  const std::size_t n = static_cast<std::size_t>(size);
  const double c = 0.5 * (size - 1), radius = s.collimation * 0.5 * size;
  auto r2_at = [&](std::size_t i, std::size_t j) {
    const double dx = static_cast<double>(j) - c, dy = static_cast<double>(i) - c;
    return dx * dx + dy * dy;
  };

  // Window: given, or from the noise-free frame inside the field (automatic brightness).
  double lo = s.level - 0.5 * s.window, hi = s.level + 0.5 * s.window;
  if (s.window <= 0.0) {
    std::vector<float> inside;
    inside.reserve(n * n);
    for (std::size_t i = 0; i < n; i += 4)
      for (std::size_t j = 0; j < n; j += 4)
        if (r2_at(i, j) < radius * radius) inside.push_back(p[i * n + j]);
    const double p_lo = percentile(inside, 0.01), p_hi = percentile(inside, 0.99);
    lo = p_lo - 0.05 * (p_hi - p_lo);
    hi = p_hi + 0.15 * (p_hi - p_lo);
  }
  if (hi <= lo) hi = lo + 1e-3;

  // Detected photons N ~ Poisson(I0 exp(-p)); for a mean above 10 the normal approximation
  // (mean and variance lambda) is used, exact Poisson sampling below.
  // Scratch kept between frames: a fresh megabyte per frame costs page faults.
  // The workers must use the caller's buffers, hence the plain references.
  thread_local std::vector<float> q_store, t_store;
  std::vector<float>& q = q_store;
  std::vector<float>& t = t_store;
  q.assign(n * n, 0.0f);
  const bool noise = s.dose > 0.0;
  const double i0 = noise ? s.dose : 1.0;
  // Rows and columns that can reach the collimated field (a pixel of blur margin).
  const double reach = radius + 2.0;
  const auto fi0 = static_cast<float>(i0);
  // Each row draws from its own generator seeded by (seed, row), so a frame is the same whatever
  // the number of threads sharing the rows.
  auto noise_rows = [&](std::size_t row_begin, std::size_t row_end) {
    std::mt19937_64 rng;
    for (std::size_t i = row_begin; i < row_end; ++i) {
      const double dy = static_cast<double>(i) - c;
      if (std::abs(dy) > reach) continue;
      rng.seed(s.seed * 0x9E3779B97F4A7C15ull + i);
      const double half = std::sqrt(std::max(0.0, reach * reach - dy * dy));
      const auto j0 = static_cast<std::size_t>(std::max(0.0, std::floor(c - half)));
      const auto j1 =
          static_cast<std::size_t>(std::min(static_cast<double>(n), std::ceil(c + half + 1)));
      for (std::size_t j = j0; j < j1; ++j) {
        const std::size_t k = i * n + j;
        const float lambda = fi0 * std::exp(-p[k]);
        float counts = lambda;
        if (noise) {
          if (lambda > 10.0f) {
            counts = lambda + std::sqrt(lambda) * normal_approx(rng);
          } else {
            // Knuth's multiplication method: about lambda uniforms.
            const double limit = std::exp(-static_cast<double>(lambda));
            double prod = 1.0;
            int k_count = -1;
            do {
              ++k_count;
              prod *= static_cast<double>(rng() >> 11) * (1.0 / 9007199254740992.0);
            } while (prod > limit);
            counts = static_cast<float>(k_count);
          }
        }
        q[k] = counts;
      }
    }
  };
  parallel_rows(n, noise_rows);

  // Correlation blur (separable 3-tap Gaussian) on the detected signal.
  if (s.blur_sigma_px > 0.0) {
    const float w1 = static_cast<float>(std::exp(-0.5 / (s.blur_sigma_px * s.blur_sigma_px)));
    const float a = 1.0f / (1.0f + 2.0f * w1), b = w1 * a;
    t.resize(n * n);
    for (std::size_t i = 0; i < n; ++i)
      for (std::size_t j = 0; j < n; ++j) {
        const std::size_t jm = j > 0 ? j - 1 : j, jp = j + 1 < n ? j + 1 : j;
        t[i * n + j] = a * q[i * n + j] + b * (q[i * n + jm] + q[i * n + jp]);
      }
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t im = i > 0 ? i - 1 : i, ip = i + 1 < n ? i + 1 : i;
      for (std::size_t j = 0; j < n; ++j)
        q[i * n + j] = a * t[i * n + j] + b * (t[im * n + j] + t[ip * n + j]);
    }
  }

  // Log, window/level (dark where attenuation is high), gamma, vignetting, collimation.
  out.assign(n * n, 0);
  const auto f_lo = static_cast<float>(lo), inv_w = static_cast<float>(1.0 / (hi - lo));
  const double inv_gamma = 1.0 / s.gamma;
  const float min_ratio = static_cast<float>(0.5 / i0), inv_i0 = static_cast<float>(1.0 / i0);
  const double r_in = std::max(0.0, radius - 1.0), r_out = radius + 1.0;
  auto display_rows = [&](std::size_t row_begin, std::size_t row_end) {
    for (std::size_t i = row_begin; i < row_end; ++i)
      for (std::size_t j = 0; j < n; ++j) {
        const double r2 = r2_at(i, j);
        if (r2 >= r_out * r_out) continue;
        // Vignetting falls with r^2; a soft collimator edge about one pixel wide.
        float field =
            static_cast<float>(1.0 - s.vignetting * std::min(1.0, r2 / (radius * radius)));
        if (r2 > r_in * r_in)
          field *= static_cast<float>(std::clamp((radius - std::sqrt(r2)) / 1.5 + 0.5, 0.0, 1.0));
        const std::size_t k = i * n + j;
        const float pe = -std::log(std::max(q[k] * inv_i0, min_ratio));
        float g = 1.0f - std::clamp((pe - f_lo) * inv_w, 0.0f, 1.0f);
        if (s.gamma != 1.0) g = static_cast<float>(std::pow(g, inv_gamma));
        out[k] = static_cast<std::uint8_t>(255.0f * std::clamp(g * field, 0.0f, 1.0f) + 0.5f);
      }
  };
  parallel_rows(n, display_rows);
}

}  // namespace vcsim
