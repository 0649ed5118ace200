# Model-edge refinement (tracking/edge_model.h, tracking/edge_refine.h), against images of the
# simulated camera (commonlight::sim renders the ground truth; tracking itself never links it).
commonlight_test(tracking edge_refine SOURCES ${CMAKE_CURRENT_SOURCE_DIR}/edge_refine_test.cpp
                 DEPS commonlight::tracking commonlight::sim TIMEOUT 600)
