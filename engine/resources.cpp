#include "engine/resources.h"
#include "engine/options.h"

#include <sys/resource.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <string>
#include <fstream>
#include <sstream>

namespace dvx {

uint64_t available_memory_bytes() {
  std::ifstream in("/proc/meminfo");
  std::string key;
  uint64_t value = 0;
  std::string unit;
  while (in >> key >> value) {
    std::getline(in, unit);
    if (key == "MemAvailable:") return value * 1024;
  }
  return 0;
}

uint64_t peak_rss_bytes() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return uint64_t(usage.ru_maxrss) * 1024;  // Linux reports KiB
}

std::string format_bytes(uint64_t bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  double value = double(bytes);
  int unit = 0;
  while (value >= 1024.0 && unit < 6) {
    value /= 1024.0;
    ++unit;
  }
  char text[64];
  std::snprintf(text, sizeof text, unit == 0 ? "%.0f %s" : "%.1f %s", value, units[unit]);
  return text;
}

bool stderr_is_tty() {
  // DIVVOX_PROGRESS=1 asks for progress lines on a pipe too (logs, tests).
  if (read_env_options().progress) return true;
  return isatty(STDERR_FILENO) == 1;
}

void progress_line(bool enabled, const std::string& text) {
  if (enabled) std::fprintf(stderr, "divvox: %s\n", text.c_str());
}

}  // namespace dvx
