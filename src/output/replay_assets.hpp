// Internal to ukdyn::io: the replay page's parts, embedded at build time (cmake/embed_web.cmake
// generates replay_assets.cpp from web/src and web/node_modules/three).
#pragma once

#include <string_view>

namespace ukdyn::replay_assets {

extern const std::string_view page_html;          ///< web/src/replay.html (placeholders @...@)
extern const std::string_view app_js;             ///< web/src/replay.js
extern const std::string_view three_js;           ///< three/build/three.module.min.js, or empty
extern const std::string_view orbit_controls_js;  ///< three/examples/jsm/controls/OrbitControls.js
extern const std::string_view three_version;      ///< from three/package.json, or empty

}  // namespace ukdyn::replay_assets
