#include "render/overlay.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

#include "render/gl_objects.h"

namespace commonlight::render {

namespace {

const char* kOverlayVs = R"(#version 330 core
out vec2 v_uv;
void main() {
    // One triangle over the whole target.
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    v_uv = p;
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
)";
const char* kOverlayFs = R"(#version 330 core
in vec2 v_uv;
out vec4 o_color;
uniform sampler2D u_texture;
uniform int u_opaque;  // 1: an RGB image drawn as is; 0: the premultiplied overlay
void main() {
    vec4 c = texture(u_texture, vec2(v_uv.x, 1.0 - v_uv.y));  // the images' top row first
    o_color = u_opaque == 1 ? vec4(c.rgb, 1.0) : c;
}
)";

// Colours as the RGBA image stores them: premultiplied by alpha.
cv::Scalar rgba(double r, double g, double b, double a = 255.0) { return {r * a / 255.0, g * a / 255.0, b * a / 255.0, a}; }

constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

// Text with a dark outline, readable over any picture.
void outlinedText(cv::Mat& image, const std::string& text, cv::Point at, double scale, const cv::Scalar& colour, int thickness) {
    cv::putText(image, text, at, kFont, scale, rgba(0, 0, 0), thickness + 2, cv::LINE_AA);
    cv::putText(image, text, at, kFont, scale, colour, thickness, cv::LINE_AA);
}

// Splits `text` at spaces into lines no wider than `max_width` pixels (a word longer than that is
// cut), at most `max_lines` (the last one then ends in "...").
std::vector<std::string> wrapText(const std::string& text, double scale, int max_width, std::size_t max_lines) {
    std::vector<std::string> lines;
    if (text.empty() || max_width <= 0 || max_lines == 0) return lines;
    int baseline = 0;
    const auto fits = [&](const std::string& s) { return cv::getTextSize(s, kFont, scale, 1, &baseline).width <= max_width; };
    std::string line;
    std::size_t pos = 0;
    while (pos <= text.size()) {
        std::size_t end = text.find(' ', pos);
        if (end == std::string::npos) end = text.size();
        std::string word = text.substr(pos, end - pos);
        pos = end + 1;
        const std::string candidate = line.empty() ? word : line + " " + word;
        if (fits(candidate)) {
            line = candidate;
            continue;
        }
        if (!line.empty()) lines.push_back(line);
        while (!fits(word) && word.size() > 1) {
            // A word wider than the line (a long path): cut it where it stops fitting.
            std::size_t n = word.size() - 1;
            while (n > 1 && !fits(word.substr(0, n))) --n;
            lines.push_back(word.substr(0, n));
            word = word.substr(n);
        }
        line = word;
    }
    if (!line.empty()) lines.push_back(line);
    if (lines.size() > max_lines) {
        lines.resize(max_lines);
        std::string& last = lines.back();
        while (!last.empty() && !fits(last + "...")) last.pop_back();
        last += "...";
    }
    return lines;
}

}  // namespace

void rasteriseOverlay(const OverlayContent& content, int width, int height, Image& out) {
    out.reshape(PixelFormat::kRgba8, width, height);
    cv::Mat image(height, width, CV_8UC4, out.data(), out.stride());
    image.setTo(cv::Scalar(0, 0, 0, 0));
    if (width <= 0 || height <= 0) return;
    // Sizes follow the target's height (designed at 480 rows).
    const double scale = std::clamp(0.45 * height / 480.0, 0.3, 1.2);
    const int line_h = std::max(10, static_cast<int>(std::lround(36.0 * scale)));
    const int pad = std::max(4, static_cast<int>(std::lround(14.0 * scale)));

    // Step 1: the tags' corners and ids, under the text (tag-detections view).
    if (!content.tags.empty()) {
        const double sx = content.image_width > 0 ? static_cast<double>(width) / content.image_width : 1.0;
        const double sy = content.image_height > 0 ? static_cast<double>(height) / content.image_height : 1.0;
        constexpr int kShift = 4;  // sub-pixel coordinates: 1/16 px
        const auto at = [&](const Eigen::Vector2d& p) {
            // Pixel centres map to pixel centres: (x + 0.5) sx - 0.5.
            return cv::Point(static_cast<int>(std::lround(((p.x() + 0.5) * sx - 0.5) * (1 << kShift))),
                             static_cast<int>(std::lround(((p.y() + 0.5) * sy - 0.5) * (1 << kShift))));
        };
        for (const OverlayTag& tag : content.tags) {
            const cv::Scalar colour = tag.in_scene ? rgba(40, 255, 60) : rgba(255, 200, 0);
            std::vector<cv::Point> quad;
            for (const Eigen::Vector2d& c : tag.corners_px) quad.push_back(at(c));
            cv::polylines(image, quad, true, colour, 2, cv::LINE_AA, kShift);
            cv::circle(image, quad[0], 4 << kShift, rgba(255, 40, 40), cv::FILLED, cv::LINE_AA, kShift);  // corner 0
            Eigen::Vector2d centre = Eigen::Vector2d::Zero();
            for (const Eigen::Vector2d& c : tag.corners_px) centre += 0.25 * c;
            const std::string id = std::to_string(tag.id);
            int baseline = 0;
            const cv::Size size = cv::getTextSize(id, kFont, scale * 1.2, 2, &baseline);
            const cv::Point mid(static_cast<int>(std::lround((centre.x() + 0.5) * sx - 0.5)),
                                static_cast<int>(std::lround((centre.y() + 0.5) * sy - 0.5)));
            outlinedText(image, id, mid + cv::Point(-size.width / 2, size.height / 2), scale * 1.2, colour, 2);
        }
    }

    // Step 2: the panel of figures, top left, on a translucent dark box.
    if (!content.lines.empty()) {
        int text_w = 0;
        for (const std::string& line : content.lines) {
            int baseline = 0;
            text_w = std::max(text_w, cv::getTextSize(line, kFont, scale, 1, &baseline).width);
        }
        const cv::Rect box(pad / 2, pad / 2, std::min(width - pad, text_w + 2 * pad),
                           std::min(height - pad, static_cast<int>(content.lines.size()) * line_h + pad));
        cv::rectangle(image, box, rgba(0, 0, 0, 150), cv::FILLED);
        for (std::size_t i = 0; i < content.lines.size(); ++i) {
            const cv::Point at(box.x + pad, box.y + pad / 2 + static_cast<int>(i + 1) * line_h - line_h / 4);
            cv::putText(image, content.lines[i], at, kFont, scale, rgba(255, 255, 255), 1, cv::LINE_AA);
        }
    }

    // Step 3: the recording mark, top right.
    if (content.recording) {
        int baseline = 0;
        const cv::Size size = cv::getTextSize(content.recording_text, kFont, scale, 1, &baseline);
        const int dot = std::max(4, line_h / 3);
        const cv::Rect box(width - pad / 2 - (size.width + 3 * pad + 2 * dot), pad / 2, size.width + 3 * pad + 2 * dot, line_h + pad);
        cv::rectangle(image, box, rgba(0, 0, 0, 150), cv::FILLED);
        cv::circle(image, cv::Point(box.x + pad + dot, box.y + box.height / 2), dot, rgba(230, 20, 20), cv::FILLED, cv::LINE_AA);
        cv::putText(image, content.recording_text, cv::Point(box.x + 2 * pad + 2 * dot, box.y + box.height / 2 + size.height / 2),
                    kFont, scale, rgba(255, 90, 90), 1, cv::LINE_AA);
    }

    // Step 4: the warning banner across the middle; its detail wrapped to the target's width.
    if (!content.banner.empty()) {
        const double big = scale * 1.5;
        int baseline = 0;
        const cv::Size size = cv::getTextSize(content.banner, kFont, big, 2, &baseline);
        const std::vector<std::string> details = wrapText(content.banner_detail, scale, width - 4 * pad, 3);
        int detail_w = 0;
        for (const std::string& line : details) detail_w = std::max(detail_w, cv::getTextSize(line, kFont, scale, 1, &baseline).width);
        const int detail_h = static_cast<int>(details.size()) * line_h;
        const int box_w = std::min(width, std::max(size.width, detail_w) + 4 * pad);
        const int box_h = size.height + detail_h + 3 * pad;
        const cv::Rect box((width - box_w) / 2, (height - box_h) / 2, box_w, box_h);
        cv::rectangle(image, box, rgba(190, 25, 25, 215), cv::FILLED);
        cv::putText(image, content.banner, cv::Point(box.x + (box_w - size.width) / 2, box.y + pad + size.height), kFont, big,
                    rgba(255, 255, 255), 2, cv::LINE_AA);
        for (std::size_t i = 0; i < details.size(); ++i) {
            const int w = cv::getTextSize(details[i], kFont, scale, 1, &baseline).width;
            cv::putText(image, details[i],
                        cv::Point(box.x + (box_w - w) / 2, box.y + 2 * pad + size.height + static_cast<int>(i + 1) * line_h - line_h / 4),
                        kFont, scale, rgba(255, 235, 235), 1, cv::LINE_AA);
        }
    }
}

Result<std::unique_ptr<Overlay>> Overlay::create(GlContext& context) {
    context.makeCurrent();
    auto overlay = std::unique_ptr<Overlay>(new Overlay());
    overlay->context_ = &context;
    CL_TRY(overlay->program_, gl::newProgram("overlay", kOverlayVs, kOverlayFs));
    overlay->vao_ = gl::newVertexArray();
    overlay->overlay_texture_ = gl::newTexture();
    overlay->image_texture_ = gl::newTexture();
    for (const auto& [texture, filter] : {std::pair{overlay->overlay_texture_, GL_NEAREST}, std::pair{overlay->image_texture_, GL_LINEAR}}) {
        glBindTexture(GL_TEXTURE_2D, texture);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, filter);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, filter);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    }
    glBindTexture(GL_TEXTURE_2D, 0);
    if (const GLenum error = glGetError(); error != GL_NO_ERROR) {
        return fail(ErrorCode::kDevice, "render: GL error " + std::to_string(error) + " while making the overlay");
    }
    return overlay;
}

Overlay::~Overlay() {
    if (context_) context_->makeCurrent();
    GLuint program = program_, vao = vao_, overlay_texture = overlay_texture_, image_texture = image_texture_;
    gl::deleteProgram(program);
    gl::deleteVertexArray(vao);
    gl::deleteTexture(overlay_texture);
    gl::deleteTexture(image_texture);
}

Result<void> Overlay::blit(unsigned texture, bool blend, unsigned target, int width, int height) {
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, target);
    if (target == 0) glDrawBuffer(GL_BACK);
    glViewport(0, 0, width, height);
    glDisable(GL_DEPTH_TEST);
    glDisable(GL_CULL_FACE);
    glDisable(GL_SCISSOR_TEST);
    if (blend) {
        glEnable(GL_BLEND);
        glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);  // premultiplied alpha
    }
    glUseProgram(program_);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, texture);
    glUniform1i(glGetUniformLocation(program_, "u_texture"), 0);
    glUniform1i(glGetUniformLocation(program_, "u_opaque"), blend ? 0 : 1);
    glBindVertexArray(vao_);
    glDrawArrays(GL_TRIANGLES, 0, 3);
    // Leave the state as the compositor expects it.
    glBindVertexArray(0);
    glBindTexture(GL_TEXTURE_2D, 0);
    glUseProgram(0);
    glDisable(GL_BLEND);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    if (const GLenum error = glGetError(); error != GL_NO_ERROR) {
        return fail(ErrorCode::kInternal, "render: GL error " + std::to_string(error) + " while drawing the overlay");
    }
    return {};
}

namespace {

// Uploads tightly packed pixels into `texture`, (re)allocating it when the size changed.
void upload(unsigned texture, GLenum format, int width, int height, const std::uint8_t* data, std::size_t stride,
            std::size_t bytes_per_pixel, int& allocated_w, int& allocated_h) {
    glBindBuffer(GL_PIXEL_UNPACK_BUFFER, 0);
    glBindTexture(GL_TEXTURE_2D, texture);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
    glPixelStorei(GL_UNPACK_ROW_LENGTH, static_cast<GLint>(stride / bytes_per_pixel));
    if (allocated_w != width || allocated_h != height) {
        glTexImage2D(GL_TEXTURE_2D, 0, format == GL_RGBA ? GL_RGBA8 : GL_RGB8, width, height, 0, format, GL_UNSIGNED_BYTE, data);
        allocated_w = width;
        allocated_h = height;
    } else {
        glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, format, GL_UNSIGNED_BYTE, data);
    }
    glPixelStorei(GL_UNPACK_ROW_LENGTH, 0);
    glBindTexture(GL_TEXTURE_2D, 0);
}

}  // namespace

Result<void> Overlay::draw(const OverlayContent& content, unsigned target, int width, int height) {
    if (width <= 0 || height <= 0) return fail(ErrorCode::kBadInput, "render: the overlay's target has no pixels");
    context_->makeCurrent();
    rasteriseOverlay(content, width, height, rgba_);
    upload(overlay_texture_, GL_RGBA, width, height, rgba_.data(), rgba_.stride(), 4, overlay_w_, overlay_h_);
    return blit(overlay_texture_, true, target, width, height);
}

Result<void> Overlay::drawImage(const ImageView& rgb8, unsigned target, int width, int height) {
    if (rgb8.format != PixelFormat::kRgb8 || rgb8.empty()) return fail(ErrorCode::kBadInput, "render: the overlay's image is not RGB8");
    if (width <= 0 || height <= 0) return fail(ErrorCode::kBadInput, "render: the overlay's target has no pixels");
    context_->makeCurrent();
    upload(image_texture_, GL_RGB, rgb8.width, rgb8.height, rgb8.data, rgb8.stride, 3, image_w_, image_h_);
    return blit(image_texture_, false, target, width, height);
}

Result<void> Overlay::drawOnWindow(const OverlayContent& content) {
    int w = 0, h = 0;
    context_->windowSize(w, h);
    return draw(content, 0, w, h);
}

void Overlay::clearWindow() {
    context_->makeCurrent();
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
    glDrawBuffer(GL_BACK);
    glClearColor(0.0f, 0.0f, 0.0f, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

Result<void> Overlay::drawImageOnWindow(const ImageView& rgb8) {
    int w = 0, h = 0;
    context_->windowSize(w, h);
    return drawImage(rgb8, 0, w, h);
}

}  // namespace commonlight::render
