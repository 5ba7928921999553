#include "engine/errors.h"

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
