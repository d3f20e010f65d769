"""The moving target: the car with its landing platform and its motion profiles."""
