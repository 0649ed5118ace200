// A test suite that shares one offscreen GL context (EGL surfaceless) among its tests; without any
// GL context the test program exits 77 (skip), never passes silently.
#pragma once

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

#include "render/gl_context.h"

namespace commonlight::render {

class GlSuite : public ::testing::Test {
protected:
    static void SetUpTestSuite() {
        auto ctx = GlContext::create({});
        if (!ctx) {
            std::fprintf(stderr, "skipped: no offscreen GL context: %s\n", ctx.error().message.c_str());
            std::exit(77);
        }
        context_ = std::move(*ctx);
    }
    static void TearDownTestSuite() { context_.reset(); }
    inline static std::unique_ptr<GlContext> context_;
};

// A window of w x h titled `title` (under Xvfb; not "commonlight": e2e/live_window looks for that).
inline Result<std::unique_ptr<GlContext>> testWindow(const std::string& title, int w, int h) {
    ContextOptions options;
    options.kind = ContextKind::kWindow;
    options.title = title;
    options.width = w;
    options.height = h;
    return GlContext::create(options);
}

}  // namespace commonlight::render
