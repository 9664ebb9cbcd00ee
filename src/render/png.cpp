// PNG output through Debian's compiled stb (libstb: stb_image_write).
#include <stb_image_write.h>

#include "vcsim/render.h"

namespace vcsim {

void write_png_grey(const std::string& path, std::span<const std::uint8_t> pixels, int width,
                    int height) {
  if (width <= 0 || height <= 0 ||
      pixels.size() != static_cast<std::size_t>(width) * static_cast<std::size_t>(height))
    throw std::invalid_argument("write_png_grey: pixel count does not match the size");
  // Noisy fluoroscopy frames barely compress: the fastest level costs little in size.
  stbi_write_png_compression_level = 2;
  if (!stbi_write_png(path.c_str(), width, height, 1, pixels.data(), width))
    throw InputError(path, "file", "a writable path for the PNG");
}

}  // namespace vcsim
