"""torch nn.Modules of the three networks. Filled by the network issues."""
