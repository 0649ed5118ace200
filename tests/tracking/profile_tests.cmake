# The edge profile (tracking/edge_profile.h): its vectorized sampling against the scalar one.
commonlight_test(tracking edge_profile SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/edge_profile_test.cpp DEPS commonlight::tracking)
