// Runs a piece of work in a forked child and brings its text result back through a pipe, so a
// benchmark configuration's peak memory (and any crash or memory refusal) is its own.
#pragma once

#include <functional>
#include <string>

namespace dvx {

// Runs `work` in a child process. True with `result` = the returned text when the child succeeded;
// false with `error` = the exception's message (or a description of how the child died).
bool run_in_child(const std::function<std::string()>& work, std::string& result, std::string& error);

}  // namespace dvx
