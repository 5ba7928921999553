// PNG capture through stb_image_write (header-only; its implementation lives here and only here).
#include "render/renderer.h"

#define STB_IMAGE_WRITE_IMPLEMENTATION
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#include <stb_image_write.h>
#pragma GCC diagnostic pop

#include <cerrno>
#include <cstring>

namespace dvx {

bool write_png(const std::string& path, int width, int height, const std::vector<uint8_t>& rgba,
               std::string& error) {
  if (width < 1 || height < 1 || rgba.size() != size_t(width) * size_t(height) * 4) {
    error = "PNG " + path + ": image is not " + std::to_string(width) + "x" + std::to_string(height) + " RGBA";
    return false;
  }
  errno = 0;
  if (!stbi_write_png(path.c_str(), width, height, 4, rgba.data(), width * 4)) {
    error = "PNG " + path + ": cannot write" + (errno ? std::string(" (") + std::strerror(errno) + ")" : std::string());
    return false;
  }
  return true;
}

}  // namespace dvx
