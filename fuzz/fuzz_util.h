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

namespace dtif::fuzz {

/// A folder of this process under the temporary folder, made once.
inline const std::filesystem::path& scratchDir() {
  static const std::filesystem::path dir = [] {
    const auto p =
        std::filesystem::temp_directory_path() / ("dtif_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(p);
    return p;
  }();
  return dir;
}

/// Writes the input to scratchDir()/name and returns its path.
inline std::string writeInput(const std::string& name, const uint8_t* data, size_t size) {
  const std::string path = (scratchDir() / name).string();
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

}  // namespace dtif::fuzz
