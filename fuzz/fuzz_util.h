// Shared by the libFuzzer targets (fuzz/README.md): inputs that only a file can carry are
// written to a temporary file of this process first.
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>

namespace dtif::fuzz {

/// A folder of this process under the temporary folder, made once and removed when the
/// process exits (libFuzzer exits normally at the end of its time; each run is a new process).
inline const std::filesystem::path& scratchDir() {
  struct Dir {
    std::filesystem::path path =
        std::filesystem::temp_directory_path() / ("dtif_fuzz_" + std::to_string(::getpid()));
    Dir() { std::filesystem::create_directories(path); }
    ~Dir() {
      std::error_code ec;
      std::filesystem::remove_all(path, ec);
    }
  };
  static const Dir dir;
  return dir.path;
}

/// Writes the input to scratchDir()/name and returns its path.
inline std::string writeInput(const std::string& name, const uint8_t* data, size_t size) {
  const std::string path = (scratchDir() / name).string();
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

}  // namespace dtif::fuzz
