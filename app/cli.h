// The divvox command line: subcommands, flags, exit codes (0 ok, 2 bad input, 1 internal).
#pragma once

namespace dvx {

// Parses argv and runs the chosen command; returns the process exit code. Never throws.
int run_cli(int argc, char** argv);

}  // namespace dvx
