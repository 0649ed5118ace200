commonlight_test(tracking tag_pose SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tag_pose_test.cpp DEPS commonlight::tracking)
commonlight_test(tracking bundle SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/bundle_test.cpp DEPS commonlight::tracking)
commonlight_test(tracking tracker SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tracker_test.cpp DEPS commonlight::tracking commonlight::capture)
commonlight_test(tracking tag_refine SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tag_refine_test.cpp DEPS commonlight::tracking commonlight::capture)
