"""Real road layers as data: planar street graph, hierarchy, blocks, fragments, surfaces."""
