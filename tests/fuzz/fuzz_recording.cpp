// libFuzzer target: see fuzz_common.h (run_recording). Only dvx::InputError may escape the code path.
#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    dvx_fuzz::run_recording(data, size);
  } catch (const dvx::InputError&) {
  }
  return 0;
}
