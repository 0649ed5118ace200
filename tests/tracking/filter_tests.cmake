# The temporal pose filter (tracking/pose_filter.h) and the SE(3) Jacobians it uses.
commonlight_test(tracking pose_filter SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/pose_filter_test.cpp DEPS commonlight::tracking)
