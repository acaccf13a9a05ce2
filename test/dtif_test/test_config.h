// Paths for tests (never taken from the working directory). CMake configures their values
// into the build folder's test_config.cpp (test/test_config.cpp.in), not into this header: the
// paths differ from clone to clone, and a header holding them would make every test that
// includes it miss ccache in a fresh clone (scripts/common.sh shares the cache between clones).
#pragma once

namespace dtif_test_config {
extern const char* const kSourceDir;
extern const char* const kConfigDir;
extern const char* const kScenesDir;
extern const char* const kSharedDataDir;
extern const char* const kTool;
}  // namespace dtif_test_config

#define DTIF_SOURCE_DIR ::dtif_test_config::kSourceDir
#define DTIF_CONFIG_DIR ::dtif_test_config::kConfigDir
#define DTIF_SCENES_DIR ::dtif_test_config::kScenesDir
/// Real third-party data (optional; tests using it skip when it is absent).
#define DTIF_SHARED_DATA_DIR ::dtif_test_config::kSharedDataDir
/// The dtif tool of this build (rostests simulate their bags with it; tool/cli_test runs it).
#define DTIF_TOOL ::dtif_test_config::kTool
