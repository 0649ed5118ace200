# Tests of the simulated camera's renderer (mocks/sim/{embree_scene,path_tracer,lights,materials,sampling,
# tag_texture,camera_rays,render}). Closed-form validations; times in docs/sim-rendering.md.
commonlight_test(sim render_irradiance SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_irradiance_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
commonlight_test(sim render_furnace SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_furnace_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
commonlight_test(sim render_projection SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_projection_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
commonlight_test(sim render_determinism SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_determinism_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
commonlight_test(sim render_hard_cases SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_hard_cases_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
commonlight_test(sim render_sampling SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_sampling_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
commonlight_test(sim render_tag SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/render_tag_test.cpp
                 DEPS commonlight::sim TIMEOUT 600)
