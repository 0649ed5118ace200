commonlight_test(tracking tag_dilation SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/tag_dilation_test.cpp
                 DEPS commonlight::tracking commonlight::sim opencv_imgproc)
