"""A view of the positioning: lamps, the train with its along-track 3σ and the last fix's
rays, as markers for RViz2 or Foxglove and as pictures drawn from a bag.
"""
