"""A fleet of simulated robots serving simulated people, over the network.

The people are the learning core's simulated users (docs/method.md §11); the robots talk to
a running Attune service only through ``attune_client``, as real robot controllers do.
"""

from .simulate import FleetRun, Person, PlayedEpisode, make_people, overall_stats, run_fleet

__all__ = ["FleetRun", "Person", "PlayedEpisode", "make_people", "overall_stats", "run_fleet"]
