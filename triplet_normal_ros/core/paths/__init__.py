"""The two ways an estimate runs: `range_image` (an organized range image, top to bottom) and `pools` (every other
cloud), sharing the call's state in `call`."""
