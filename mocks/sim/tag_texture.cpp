#include "mocks/sim/tag_texture.h"

#include <apriltag/apriltag.h>
#include <apriltag/tag16h5.h>
#include <apriltag/tag25h9.h>
#include <apriltag/tag36h11.h>
#include <apriltag/tagCircle21h7.h>
#include <apriltag/tagCircle49h12.h>
#include <apriltag/tagCustom48h12.h>
#include <apriltag/tagStandard41h12.h>
#include <apriltag/tagStandard52h13.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <memory>

namespace commonlight::mocks::sim {

namespace {

struct FamilyFunctions {
    const char* name;
    apriltag_family_t* (*create)();
    void (*destroy)(apriltag_family_t*);
};

constexpr FamilyFunctions kFamilies[] = {
    {"tag36h11", tag36h11_create, tag36h11_destroy},
    {"tag25h9", tag25h9_create, tag25h9_destroy},
    {"tag16h5", tag16h5_create, tag16h5_destroy},
    {"tagCircle21h7", tagCircle21h7_create, tagCircle21h7_destroy},
    {"tagCircle49h12", tagCircle49h12_create, tagCircle49h12_destroy},
    {"tagCustom48h12", tagCustom48h12_create, tagCustom48h12_destroy},
    {"tagStandard41h12", tagStandard41h12_create, tagStandard41h12_destroy},
    {"tagStandard52h13", tagStandard52h13_create, tagStandard52h13_destroy},
};

// Frees an image from apriltag_to_image. image_u8_destroy is not exported by Debian's library;
// the image and its buffer are plain malloc'd blocks.
struct ImageU8Deleter {
    void operator()(image_u8_t* image) const noexcept {
        if (image == nullptr) return;
        std::free(image->buf);
        std::free(image);
    }
};

}  // namespace

Result<TagTexture> TagTexture::make(const std::string& family, int id) {
    const auto it = std::find_if(std::begin(kFamilies), std::end(kFamilies),
                                 [&](const FamilyFunctions& f) { return family == f.name; });
    if (it == std::end(kFamilies)) return fail(ErrorCode::kBadInput, "unknown tag family '" + family + "'");
    // Owned here; destroyed by the family's own destroy function when this scope ends.
    const std::unique_ptr<apriltag_family_t, void (*)(apriltag_family_t*)> fam(it->create(), it->destroy);
    if (!fam) return fail(ErrorCode::kInternal, "libapriltag could not create family '" + family + "'");
    if (id < 0 || static_cast<std::uint32_t>(id) >= fam->ncodes) {
        return fail(ErrorCode::kBadInput, "tag id " + std::to_string(id) + " is not in family '" + family + "' (0 to " +
                                              std::to_string(fam->ncodes - 1) + ")");
    }
    // Owned here (see ImageU8Deleter).
    const std::unique_ptr<image_u8_t, ImageU8Deleter> image(apriltag_to_image(fam.get(), id));
    if (!image || image->width != image->height || image->width != fam->total_width) {
        return fail(ErrorCode::kInternal,
                    "libapriltag drew an unexpected image for " + family + " id " + std::to_string(id));
    }
    TagTexture texture;
    texture.id_ = id;
    texture.total_width_ = fam->total_width;
    texture.width_at_border_ = fam->width_at_border;
    texture.cells_.resize(static_cast<std::size_t>(image->width) * image->height);
    for (int y = 0; y < image->height; ++y) {
        for (int x = 0; x < image->width; ++x) {
            texture.cells_[static_cast<std::size_t>(y) * image->width + x] = image->buf[y * image->stride + x] > 127;
        }
    }
    return texture;
}

double PlacedTag::albedoAt(double x, double y) const noexcept {
    const int n = texture.totalWidth();
    const double cell = 2.0 * half_extent / n;
    // Column from the left edge (-x), row from the top edge (+y: the image's top row), in cells.
    const double u = (x + half_extent) / cell, v = (half_extent - y) / cell;
    const auto column = [n](double c) { return std::clamp(static_cast<int>(std::floor(c)), 0, n - 1); };
    if (ink_spread_cells == 0.0) return texture.isWhite(column(u), column(v)) ? albedo_white : albedo_black;
    // Ink spread: the colour that spreads wins if any cell within the spread (a square of half
    // side |spread| around the point: at most four cells) has it.
    const double e = std::abs(ink_spread_cells);
    const bool spreading_white = ink_spread_cells < 0.0;
    for (const double du : {-e, e}) {
        for (const double dv : {-e, e}) {
            if (texture.isWhite(column(u + du), column(v + dv)) == spreading_white) {
                return spreading_white ? albedo_white : albedo_black;
            }
        }
    }
    return spreading_white ? albedo_black : albedo_white;
}

Result<std::vector<PlacedTag>> makePlacedTags(const TagSet& tags, double ink_spread_cells) {
    if (!(std::abs(ink_spread_cells) <= 0.25)) {
        return fail(ErrorCode::kBadInput, "tag ink spread " + std::to_string(ink_spread_cells) +
                                              " cells is out of range [-0.25, 0.25]");
    }
    std::vector<PlacedTag> placed;
    for (const TagItem& item : tags.items) {
        if (!(item.size > 0.0)) continue;
        auto texture = TagTexture::make(tags.family, item.id);
        if (!texture) return fail(std::move(texture).error().prepend("tag " + std::to_string(item.id)));
        PlacedTag tag;
        tag.texture = std::move(*texture);
        tag.world_from_tag = item.world_from_tag;
        tag.tag_from_world = item.world_from_tag.inverse();
        tag.size = item.size;
        const double cell = item.size / tag.texture.widthAtBorder();
        tag.half_extent = 0.5 * cell * tag.texture.totalWidth();
        tag.albedo_black = item.albedo_black;
        tag.albedo_white = item.albedo_white;
        tag.ink_spread_cells = ink_spread_cells;
        placed.push_back(std::move(tag));
    }
    return placed;
}

}  // namespace commonlight::mocks::sim
