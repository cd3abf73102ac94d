"""The tracking stages of Shu 2007 and Hu 2013, each in the module named after it."""
