// What the machine has: memory available, peak memory used, and byte formatting.
#pragma once

#include <cstdint>
#include <string>

namespace dvx {

// MemAvailable from /proc/meminfo (bytes); 0 when unknown.
uint64_t available_memory_bytes();
// Peak resident set size of this process (bytes).
uint64_t peak_rss_bytes();
// "1.5 GiB", "320 MiB", "12 KiB".
std::string format_bytes(uint64_t bytes);
// True when stderr is a terminal (progress is shown only then) or DIVVOX_PROGRESS=1.
bool stderr_is_tty();
// One progress line on stderr ("divvox: TEXT") when `enabled`.
void progress_line(bool enabled, const std::string& text);

}  // namespace dvx
