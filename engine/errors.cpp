#include "engine/errors.h"

namespace dvx {

std::string input_message(const std::string& file, const std::string& problem) {
  std::string line = file.empty() ? problem : file + ": " + problem;
  for (char& c : line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  while (!line.empty() && line.back() == ' ') line.pop_back();
  return line;
}

}  // namespace dvx
