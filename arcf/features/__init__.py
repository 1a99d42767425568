"""Hand-crafted features of the ARCF trackers: fHOG, grayscale and Color Names."""
