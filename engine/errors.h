// Errors that leave the program with a one-line message and an exit code:
// 2 for bad input (a file, a flag, a value), 1 for internal failures.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace dvx {

enum ExitCode : int { kExitOk = 0, kExitInternal = 1, kExitBadInput = 2 };

// Bad input: the message names the file (or flag) and the problem, on one line.
struct InputError : std::runtime_error {
  explicit InputError(const std::string& message) : std::runtime_error(message) {}
};

// "FILE: problem" with newlines folded so the message stays on one line.
std::string input_message(const std::string& file, const std::string& problem);

[[noreturn]] inline void throw_input(const std::string& file, const std::string& problem) {
  throw InputError(input_message(file, problem));
}

// A comma-separated list of integers given to `flag` ("64,128,256"), each in [low, high]; anything
// else throws InputError "FLAG: 'ITEM' is not an integer in [LOW, HIGH]". Shared by divvox's and
// divvox_peers' list flags (--resolutions, --iterations).
std::vector<int> parse_int_list(const std::string& flag, const std::string& text, int low, int high);

// Inside a catch block: prints the exception being handled as one line on stderr and returns its exit
// code — InputError "PROGRAM: error: MESSAGE", 2; out of memory "PROGRAM: error: out of memory", 1;
// anything else "PROGRAM: internal error: MESSAGE", 1. The last step of every program's main.
int exit_for_current_exception(const char* program);

}  // namespace dvx
