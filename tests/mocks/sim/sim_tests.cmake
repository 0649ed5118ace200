commonlight_test(sim trajectory SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/trajectory_test.cpp DEPS commonlight::sim)
commonlight_test(sim simulation SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/simulation_test.cpp DEPS commonlight::sim opencv_imgproc opencv_imgcodecs TIMEOUT 600)
commonlight_test(sim sim_camera SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/sim_camera_test.cpp DEPS commonlight::sim commonlight::capture TBB::tbb
                 LABELS threads TIMEOUT 600)
