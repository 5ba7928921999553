#include "engine/errors.h"

#include <algorithm>
#include <cstdio>
#include <exception>
#include <new>

namespace dvx {

std::string input_message(const std::string& file, const std::string& problem) {
  std::string line = file.empty() ? problem : file + ": " + problem;
  for (char& c : line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  while (!line.empty() && line.back() == ' ') line.pop_back();
  return line;
}

std::vector<int> parse_int_list(const std::string& flag, const std::string& text, int low, int high) {
  std::vector<int> values;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = std::min(text.find(',', start), text.size());
    const std::string item = text.substr(start, end - start);
    try {
      size_t used = 0;
      const int value = std::stoi(item, &used);
      if (used != item.size() || value < low || value > high) throw std::invalid_argument(item);
      values.push_back(value);
    } catch (const std::exception&) {
      throw_input(flag, "'" + item + "' is not an integer in [" + std::to_string(low) + ", " + std::to_string(high) + "]");
    }
    start = end + 1;
  }
  return values;
}

int exit_for_current_exception(const char* program) {
  try {
    throw;
  } catch (const InputError& e) {
    std::fprintf(stderr, "%s: error: %s\n", program, e.what());
    return kExitBadInput;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "%s: error: out of memory\n", program);
    return kExitInternal;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "%s: internal error: %s\n", program, e.what());
    return kExitInternal;
  } catch (...) {
    std::fprintf(stderr, "%s: internal error: unknown exception\n", program);
    return kExitInternal;
  }
}

}  // namespace dvx
