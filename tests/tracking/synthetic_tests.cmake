# Tracking tests on synthetic frames (tests/tracking/synthetic_tags.h renders them with mocks/sim's
# tag texture). The instant a pose is for (the middle of the exposure), on motion-blurred frames.
add_library(commonlight_test_synthetic_tags STATIC ${CMAKE_CURRENT_SOURCE_DIR}/synthetic_tags.cpp)
target_link_libraries(commonlight_test_synthetic_tags PUBLIC commonlight_options commonlight::core commonlight::sim
                      opencv_imgproc)
commonlight_test(tracking timestamps SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/timestamps_test.cpp
                 DEPS commonlight::tracking commonlight_test_synthetic_tags)
# Ambiguous single tags: reported as such alone, chosen by a second tag in view.
commonlight_test(tracking ambiguity SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/ambiguity_test.cpp
                 DEPS commonlight::tracking commonlight_test_synthetic_tags)
# The proxies' edges choose a small single tag's candidate (desk scene, rendered by mocks/sim).
commonlight_test(tracking ambiguity_edges SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/ambiguity_edges_test.cpp
                 DEPS commonlight::tracking commonlight::sim)
# Tiny tags (7-10 px): verified at their predicted place; absent, occluded or wrong ones refused.
commonlight_test(tracking tiny_tags SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tiny_tags_test.cpp
                 DEPS commonlight::tracking commonlight_test_synthetic_tags)
# ... and in a sequence: a tag the last frame reported is verified on its pattern alone.
commonlight_test(tracking tiny_tags_sequence SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tiny_tags_sequence_test.cpp
                 DEPS commonlight::tracking commonlight_test_synthetic_tags)
# The decimated detector on a window finds what it finds on the whole frame, at any window origin.
commonlight_test(tracking detector_windows SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/detector_windows_test.cpp
                 DEPS commonlight::tracking commonlight_test_synthetic_tags)
# The alignment's corner clearance, tested before the projection (tracking/tag_align.cpp).
commonlight_test(tracking tag_align_clearance SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tag_align_clearance_test.cpp
                 DEPS commonlight::tracking commonlight_test_synthetic_tags)
