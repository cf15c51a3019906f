"""Learning: networks and datasets shared by rl/ and supervised/, with the agents, dataset
collection and the shipped navigators on top of them."""
