/* fuzz_frame.c — libFuzzer target (make fuzz); the body is in fuzz_bodies.h. */
#include "tests/fuzz/fuzz_bodies.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    return fuzz_frame_body(data, size);
}
