// The page's files (src/dashboard/web/), built into the binary by cmake/EmbedFiles.cmake.
#pragma once

#include <optional>
#include <string_view>

namespace icars::dashboard {

struct Asset {
  std::string_view body;
  std::string_view content_type;
};

// The file named `name` ("index.html", "app.js"), or nullopt.
std::optional<Asset> find_asset(std::string_view name);

}  // namespace icars::dashboard
