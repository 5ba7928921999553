// libFuzzer target: see fuzz_common.h (run_scene). Only dvx::InputError may escape the code path.
#include "fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    dvx_fuzz::run_scene(data, size);
  } catch (const dvx::InputError&) {
  }
  return 0;
}
